"""``vispeech rig``: Taylor-style rig-space retargeting (reference poses out, artist poses in)."""

from __future__ import annotations

from pathlib import Path

import click

from vispeech.cli import main
from vispeech.cli.evaluate import language_option, open_corpus
from vispeech.errors import VispeechError


@main.group("rig")
def rig_group() -> None:
    """Retarget ARKit mouth tracks onto any rig through poses an artist makes (Taylor et al. 2017)."""


def _fit_corpus(directory: Path, language: str):
    """A rig space fitted on the tracked frames of every utterance of a corpus folder, and the corpus."""
    from vispeech.motion.rigspace import RigSpace
    from vispeech.motion.track import Track

    corpus = open_corpus(directory, language)
    tracks = []
    for u in corpus:
        keep = slice(None) if u.frame_mask is None else u.frame_mask
        tracks.append(Track(u.track.values[keep], u.track.channels, u.track.fps))
    return RigSpace().fit(tracks), corpus


def _space_option(required: bool):
    return click.option("--space", "-s", "space_dir", type=click.Path(file_okay=False, path_type=Path),
                        required=required, default=None, help="Rig-space folder (from export-poses --space or import).")


@rig_group.command("export-poses")
@click.option("--corpus", "corpus_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Corpus whose mouth tracks give the principal modes.")
@click.option("--output", "-o", "output", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="Pose sheet: .json or .csv.")
@click.option("--modes", "n_modes", default=4, show_default=True, type=click.IntRange(min=1), help="Modes to pose.")
@click.option("--sigma", default=3.0, show_default=True, type=click.FloatRange(min=0, min_open=True),
              help="Reference poses at ± this many standard deviations.")
@click.option("--save-space", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Also save the fitted rig space (modes without rig poses) in this folder.")
@language_option
def export_poses(corpus_dir: Path, output: Path, n_modes: int, sigma: float, save_space: Path | None,
                 language: str) -> None:
    """Write the mean and ±3σ poses of the first principal modes of a corpus's mouth, for an artist."""
    space, corpus = _fit_corpus(corpus_dir, language)
    space.write_pose_sheet(output, n_modes, (-sigma, sigma))
    shares = ", ".join(f"{100 * e:.1f}" for e in space.explained[:n_modes])
    click.echo(f"{corpus.name}: {len(space.channels)} channels; modes 1-{n_modes} explain "
               f"{100 * space.explained[:n_modes].sum():.1f} % of the variance ({shares} %)")
    click.echo(f"{1 + 2 * n_modes} poses -> {output}")
    if save_space is not None:
        space.save(save_space)
        click.echo(f"rig space -> {save_space}")


@rig_group.command("import")
@click.argument("rig_poses", type=click.Path(dir_okay=False, path_type=Path))
@_space_option(required=False)
@click.option("--corpus", "corpus_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Fit the modes on this corpus instead of reading --space.")
@click.option("--output", "-o", "output", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Folder to save the rig space with its rig poses in.")
@language_option
def import_poses(rig_poses: Path, space_dir: Path | None, corpus_dir: Path | None, output: Path, language: str) -> None:
    """Attach an artist's RIG_POSES (JSON: {"poses": {"mean": {...}, "mode1-3sd": {...}, ...}}) to a rig space."""
    from vispeech.motion.rigspace import RigSpace

    if (space_dir is None) == (corpus_dir is None):
        raise VispeechError("give exactly one of --space and --corpus")
    space = RigSpace.load(space_dir) if space_dir is not None else _fit_corpus(corpus_dir, language)[0]
    space.load_rig(rig_poses)
    space.save(output)
    click.echo(f"{len(space.rig_controls)} rig controls on modes {', '.join(map(str, space.rig_poses))} -> {output}")


@rig_group.command("retarget")
@click.argument("input_path", metavar="INPUT", type=click.Path(dir_okay=False, path_type=Path))
@_space_option(required=True)
@click.option("--rig", "rig_poses", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Rig-pose JSON to use instead of the one saved with the space.")
@click.option("--output", "-o", "output", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="Output track (.json; .csv when the rig controls are ARKit names).")
def retarget_command(input_path: Path, space_dir: Path, rig_poses: Path | None, output: Path) -> None:
    """Retarget the ARKit track INPUT onto the rig's controls."""
    from vispeech.motion.io import read_track, write_track
    from vispeech.motion.rigspace import RigSpace

    space = RigSpace.load(space_dir)
    if rig_poses is not None:
        space.load_rig(rig_poses)
    track = space.retarget(read_track(input_path))
    write_track(track, output)
    click.echo(f"{output}: {track.n_frames} frames of {len(track.channels)} rig controls at {track.fps:g} fps")
