"""``vispeech convert INPUT OUTPUT``: between track formats, with resampling and retargeting."""

from __future__ import annotations

import warnings
from pathlib import Path

import click

from vispeech.cli import main, scale_option
from vispeech.errors import UnshownChannelsWarning
from vispeech.motion.formats.registry import FORMATS, read_animation, write_track


@main.command("convert")
@click.argument("input_path", metavar="INPUT", type=click.Path(path_type=Path))
@click.argument("output", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "--to", "fmt", metavar="FORMAT", help=f"Output format: {', '.join(FORMATS)} (default: from OUTPUT's extension)."
)
@click.option("--fps", type=float, help="Resample to this many frames per second.")
@click.option(
    "--pose-table",
    help="Pose table (JSON file or built-in name): retargets the track, or for "
    "oculus/rhubarb replaces the ARKit -> visemes/shapes table (rhubarb: cues from the frames, not the phones).",
)
@click.option(
    "--glb",
    "base_glb",
    type=click.Path(path_type=Path),
    help="Base model with ARKit-named morph targets for gltf and fbx [default: the shipped ICT-FaceKit head].",
)
@click.option(
    "--uncompressed",
    is_flag=True,
    help="gltf: decode the base model's meshopt compression (about 6x larger) for importers without "
    "EXT_meshopt_compression, such as Blender and Maya [default: kept compressed, as three.js reads it].",
)
@scale_option("tracker")
def convert_command(
    input_path: Path,
    output: Path,
    fmt: str | None,
    fps: float | None,
    pose_table: str | None,
    base_glb: Path | None,
    uncompressed: bool,
    scale: str,
) -> None:
    """Read a track from INPUT (Live Link CSV, vispeech JSON, TalkingHead JSON) and write OUTPUT.

    Extensions: .csv livelink, .json json, .talkinghead.json talkinghead, .visemes.csv and
    .visemes.json oculus, .tsv and .rhubarb.json rhubarb, .glb gltf and .fbx fbx (Blender) onto the
    --glb model, by default the shipped head (ICT-FaceKit, MIT licence), whose compression a .glb
    keeps unless --uncompressed; channels the model has no morph target for are named in a
    warning. The track is taken as it is (--scale tracker); --scale arkit or a calibration file
    rescales a track in the models' scale on the way.
    """
    from vispeech.limits import check_fps
    from vispeech.motion.rigging.calibration import load_scale
    from vispeech.motion.rigging.retarget import PoseTable

    if fps is not None:
        check_fps(fps, "--fps")
    fmt = fmt.lower() if fmt else None
    calibration = load_scale(scale)
    animation = read_animation(input_path)
    track = animation.track
    if fps is not None:
        track = track.resample(fps)
    if calibration is not None:
        track = calibration.apply(track)
    table = PoseTable.load(pose_table) if pose_table else None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", UnshownChannelsWarning)
        write_track(
            track,
            output,
            fmt,
            phones=animation.phones,
            audio=animation.audio,
            base_glb=base_glb,
            pose_table=table,
            uncompressed=uncompressed,
        )
    for warning in caught:
        click.echo(f"warning: {warning.message}", err=True)
    click.echo(f"{output}: {track.n_frames} frames at {track.fps:g} fps, {track.duration:.2f} s")
