"""``vispeech rig``: Taylor-style rig-space retargeting (reference poses out, artist poses in)."""

from __future__ import annotations

from pathlib import Path

import click

from vispeech.cli import main
from vispeech.cli._corpus_input import corpus_language_option, open_corpus
from vispeech.errors import VispeechError


@main.group("rig")
def rig_group() -> None:
    """Retarget ARKit mouth tracks onto any rig through poses an artist makes (Taylor et al. 2017)."""


def _fit_corpus(directory: Path, language: str):
    """A rig space fitted on the tracked frames of every utterance of a corpus folder, and the corpus."""
    from vispeech.corpus.corpus import recorded_track
    from vispeech.motion.rigging.rigspace import RigSpace
    from vispeech.motion.track import Track

    corpus = open_corpus(directory, language)
    tracks = []
    for u in corpus:
        keep = slice(None) if u.frame_mask is None else u.frame_mask
        track = recorded_track(u)
        tracks.append(Track(track.values[keep], track.channels, track.fps))
    return RigSpace().fit(tracks), corpus


def _space_option(required: bool):
    return click.option(
        "--space",
        "-s",
        "space_dir",
        type=click.Path(file_okay=False, path_type=Path),
        required=required,
        default=None,
        help="Rig-space folder (from export-poses --save-space or import).",
    )


@rig_group.command("export-poses")
@click.option(
    "--corpus",
    "corpus_dir",
    required=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="Corpus whose mouth tracks give the principal modes.",
)
@click.option(
    "--output",
    "-o",
    "output",
    required=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help="Pose sheet: .json or .csv.",
)
@click.option("--modes", "n_modes", default=4, show_default=True, type=click.IntRange(min=1), help="Modes to pose.")
@click.option(
    "--sigma",
    default=3.0,
    show_default=True,
    type=click.FloatRange(min=0, max=10, min_open=True),
    help="Reference poses at ± this many standard deviations.",
)
@click.option(
    "--save-space",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Also save the fitted rig space (modes without rig poses) in this folder.",
)
@corpus_language_option
def export_poses(
    corpus_dir: Path, output: Path, n_modes: int, sigma: float, save_space: Path | None, language: str
) -> None:
    """Write the mean and ±3σ poses of the first principal modes of a corpus's mouth, for an artist."""
    from vispeech.files import check_output_dir, check_output_file
    from vispeech.motion.rigging.rigspace import SPACE_ARRAYS, SPACE_JSON

    check_output_file(output)  # both outputs before the work
    if save_space is not None:
        check_output_dir(save_space, replaces=(SPACE_JSON, SPACE_ARRAYS))
    space, corpus = _fit_corpus(corpus_dir, language)
    space.write_pose_sheet(output, n_modes, (-sigma, sigma))
    shares = ", ".join(f"{100 * e:.1f}" for e in space.explained[:n_modes])
    click.echo(
        f"{corpus.name}: {len(space.channels)} channels; modes 1-{n_modes} explain "
        f"{100 * space.explained[:n_modes].sum():.1f} % of the variance ({shares} %)"
    )
    click.echo(f"{1 + 2 * n_modes} poses -> {output}")
    if save_space is not None:
        space.save(save_space)
        click.echo(f"rig space -> {save_space}")


@rig_group.command("import")
@click.argument("rig_poses", type=click.Path(dir_okay=False, path_type=Path))
@_space_option(required=False)
@click.option(
    "--corpus",
    "corpus_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Fit the modes on this corpus instead of reading --space.",
)
@click.option(
    "--output",
    "-o",
    "output",
    required=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="Folder to save the rig space with its rig poses in.",
)
@corpus_language_option
def import_poses(rig_poses: Path, space_dir: Path | None, corpus_dir: Path | None, output: Path, language: str) -> None:
    """Attach an artist's RIG_POSES (JSON: {"poses": {"mean": {...}, "mode1-3sd": {...}, ...}}) to a rig space."""
    from vispeech.files import check_output_dir
    from vispeech.motion.rigging.rigspace import SPACE_ARRAYS, SPACE_JSON, RigSpace

    if (space_dir is None) == (corpus_dir is None):
        raise VispeechError("give exactly one of --space and --corpus")
    check_output_dir(output, replaces=(SPACE_JSON, SPACE_ARRAYS))
    if space_dir is not None:
        space = RigSpace.load(space_dir)
    else:
        assert corpus_dir is not None  # exactly one of the two, checked above
        space = _fit_corpus(corpus_dir, language)[0]
    space.load_rig(rig_poses)
    space.save(output)
    click.echo(f"{len(space.rig_controls)} rig controls on modes {', '.join(map(str, space.rig_poses))} -> {output}")


@rig_group.command("retarget")
@click.argument("input_path", metavar="INPUT", type=click.Path(dir_okay=False, path_type=Path))
@_space_option(required=True)
@click.option(
    "--rig",
    "rig_poses",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Rig-pose JSON to use instead of the one saved with the space.",
)
@click.option(
    "--output",
    "-o",
    "output",
    required=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help="Output track (.json; .csv when the rig controls are ARKit names).",
)
def retarget_command(input_path: Path, space_dir: Path, rig_poses: Path | None, output: Path) -> None:
    """Retarget the ARKit track INPUT onto the rig's controls."""
    from vispeech.motion.formats.registry import read_track, track_format, write_track
    from vispeech.motion.rigging.rigspace import RigSpace

    if track_format(output) not in ("json", "livelink"):  # a rig's controls are no head's morph targets
        raise VispeechError(f"{output}: write the rig's controls as .json (or .csv when they are ARKit names)")
    space = RigSpace.load(space_dir)
    if rig_poses is not None:
        space.load_rig(rig_poses)
    track = space.retarget(read_track(input_path))
    write_track(track, output)
    click.echo(f"{output}: {track.n_frames} frames of {len(track.channels)} rig controls at {track.fps:g} fps")


@rig_group.command("calibrate")
@click.argument("head", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "--output",
    "-o",
    "output",
    required=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help="Calibration file to write (.json), for --scale.",
)
@click.option(
    "--corpus",
    "corpus_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Fit to this corpus's training split [default: the shipped sample of grid_s1's frames].",
)
@click.option(
    "--frames",
    "frames_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Fit to these mouth frames (from `vispeech rig mouth-frames`).",
)
@corpus_language_option
def calibrate(head: Path, output: Path, corpus_dir: Path | None, frames_path: Path | None, language: str) -> None:
    """Fit the gains that make HEAD's lips (a GLB with ARKit morph targets) open and spread as the
    tracked human's do: its inner-lip gap and mouth width over its eye-corner distance follow
    the speaker's (docs/calibration.md). --scale FILE applies the result."""
    from vispeech.motion.rigging.calibration import HeadGeometry, fit_calibration, load_mouth_frames

    if corpus_dir is not None and frames_path is not None:
        raise VispeechError("give --corpus or --frames, not both")
    geometry = HeadGeometry.from_glb(head)
    if corpus_dir is not None:
        from vispeech.corpus.articulation import mouth_frames

        scores, gap, width = mouth_frames(open_corpus(corpus_dir, language).split("train"))
        source = f"{corpus_dir.name}, training split"
    else:
        scores, gap, width, source = load_mouth_frames(frames_path)
    calibration = fit_calibration(geometry, scores, gap, width, head.name)
    calibration = type(calibration)(calibration.gains, calibration.head, {**calibration.fit, "frames_from": source})
    calibration.save(output)
    fit = calibration.fit
    click.echo(
        f"{head.name}: eye-corner distance {geometry.eye_distance:.4g} (model units); "
        f"{fit['frames']} frames of {source}"
    )
    click.echo(
        f"inner-lip gap, head / human over open frames: median {fit['raw']['median_ratio']:.2f} -> "
        f"{fit['calibrated']['median_ratio']:.2f}, 90th percentile {fit['raw']['p90_ratio']:.2f} -> "
        f"{fit['calibrated']['p90_ratio']:.2f}"
    )
    click.echo(f"jawOpen x{calibration.gains.get('jawOpen', 1.0):.2f} ... {len(calibration.gains)} gains -> {output}")


@rig_group.command("prepare")
@click.argument("head", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "--output",
    "-o",
    "output",
    required=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help="The prepared head to write (.glb).",
)
def prepare(head: Path, output: Path) -> None:
    """Give HEAD (a GLB with ARKit morph targets) the tongue morph targets it lacks, built from its own
    tongue geometry, lay the tongue low and let the upper teeth show, and on flat materials paint
    lips, brows, complexion and the mouth's depth and grow hair and eyelashes (docs/avatar.md).
    vispeech serve --avatar does this by itself."""
    from vispeech.motion.rigging.head import prepare_head

    if output.resolve() == head.resolve():
        raise VispeechError(f"{output}: write the prepared head to another file than {head.name}")
    report = prepare_head(head, output)
    click.echo(
        f"{head.name}: tongue morph targets {', '.join(report.targets) or 'none added'}; "
        f"reshaped {', '.join(report.reshaped) or 'nothing'}; painted {', '.join(report.painted) or 'nothing'}; "
        f"added {', '.join(report.added) or 'nothing'}"
    )
    for note in report.notes:
        click.echo(f"note: {note}")
    click.echo(f"-> {output}")


@rig_group.command("mouth-frames")
@click.option(
    "--corpus",
    "corpus_dir",
    required=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="Corpus with lip and eye landmarks (grid_s1).",
)
@click.option(
    "--output",
    "-o",
    "output",
    required=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help="Sample to write (.npz), for rig calibrate --frames.",
)
@click.option(
    "--frames",
    "n_frames",
    default=5000,
    show_default=True,
    type=click.IntRange(min=10),
    help="Random tracked frames of the training split to keep.",
)
@click.option("--seed", default=0, show_default=True, type=click.IntRange(min=0), help="Seed of the random sample.")
@corpus_language_option
def mouth_frames_command(corpus_dir: Path, output: Path, n_frames: int, seed: int, language: str) -> None:
    """Keep a sample of a corpus's tracked frames with the speaker's lip gap and mouth width:
    what rig calibrate fits heads to without the corpus (the shipped sample is grid_s1's)."""
    from vispeech.corpus.articulation import mouth_frames
    from vispeech.files import check_output_file
    from vispeech.motion.rigging.calibration import save_mouth_frames

    check_output_file(output)
    corpus = open_corpus(corpus_dir, language).split("train")
    scores, gap, width = mouth_frames(corpus)
    source = f"{corpus.name}: {min(n_frames, scores.n_frames)} random tracked frames of the training split, seed {seed}"
    save_mouth_frames(output, scores, gap, width, frames=n_frames, seed=seed, source=source)
    click.echo(f"{source} -> {output}")
