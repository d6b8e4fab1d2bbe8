"""Phones → Live Link CSV in one process: vispeech against OpenFaceFX over the same TextGrids.

    python benchmarks/bench_phones_to_csv.py [--utterances N] [--fps FPS] [--passes P]
                                             [--out DIR] [--keep DIR] [--profile]

The TextGrids: N held-out grid_s1 utterances (the test split's 83, then the validation
split's), their phones from the corpus's forced alignment (:func:`vispeech.corpus.align_corpus`,
cached) written by :func:`vispeech.alignment.formats.write_alignment` into a temporary folder.
Both tools then do the same work on each file, in this process, one core:

- vispeech: read the TextGrid (:func:`~vispeech.alignment.formats.read_alignment`), animate it
  with ``grid-tdnn`` and the post-processing it recommends (:func:`vispeech.pipeline.animate`),
  and write ``animation.csv`` (Live Link Face, ARKit scale) as an output folder that is old or
  new and whole after a kill (:func:`vispeech.pipeline.write_outputs` with ``formats=("livelink",)``);
- OpenFaceFX (``pip install openfacefx``, imported only here): ``load_mfa_textgrid``,
  ``generate_from_alignment``, ``retarget`` onto its ``arkit`` preset and
  ``write_livelink_csv``, at the same frame rate.

Prints milliseconds per utterance for each stage (read, model, post-processing, write) and
for the whole path, wall and CPU time, each the best of ``--passes`` passes with the garbage
collector paused (as :mod:`timeit` does); then the two whole paths run side by side, one
after the other on each utterance, so that a busy machine slows both alike, and the ratio of
their times (the median of the passes'). Target (issue 25): vispeech ≥ 10× OpenFaceFX. On an
idle core the wall time is the CPU time plus the waits for the disk (vispeech's fsyncs). ``--keep DIR`` keeps vispeech's CSV folders and its tracks (``tracks.npz``,
before the output scale) to compare two versions of the code; ``--profile`` prints the
vispeech path's cProfile (functions by own time). Output folders go under ``--out`` (default:
a temporary folder), a disk folder so that the fsyncs cost what they cost.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import gc  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from collections.abc import Callable  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from vispeech.alignment.formats import read_alignment, write_alignment  # noqa: E402
from vispeech.models.registry import load_model  # noqa: E402
from vispeech.pipeline import animate, write_outputs  # noqa: E402
from vispeech.postprocess import PostprocessConfig, postprocess  # noqa: E402
from vispeech.utterance import Utterance  # noqa: E402

GRID = Path(__file__).resolve().parents[2] / "shared" / "data" / "grid_s1"
MODEL = "grid-tdnn"
TARGET = 10.0
"""How many times faster than OpenFaceFX vispeech's whole path must be."""


def held_out_textgrids(folder: Path, n: int) -> list[Path]:
    """``n`` held-out grid_s1 utterances (test split, then validation) as TextGrids in ``folder``."""
    from vispeech.corpus import CorpusWarning, align_corpus, read_grid

    if not GRID.is_dir():
        raise SystemExit(f"needs the GRID corpus at {GRID}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CorpusWarning)
        corpus = read_grid(GRID)
    held = [*corpus.split("test"), *corpus.split("validation")][:n]
    align_corpus(replace(corpus, utterances=held), progress=False)
    paths = []
    for utterance in held:
        if utterance.phones is None:
            continue  # failed to align (named in a warning)
        path = folder / f"{utterance.id}.TextGrid"
        write_alignment(utterance.phones, path)
        paths.append(path)
    return paths


Stages = dict[str, Callable[[int], object]]
"""A tool's path, stage by stage and whole (``"whole"``): each runs on utterance ``i``."""


def best_pass(run: Callable[[int], object], n: int, passes: int) -> tuple[float, float]:
    """Wall and CPU seconds per utterance of the fastest of ``passes`` runs of ``run(i)`` for every
    ``i < n`` (each the least of its kind), the collector paused."""
    walls, cpus = [], []
    for _ in range(passes):
        gc.collect()
        gc.disable()
        try:
            wall, cpu = time.perf_counter(), time.process_time()
            for i in range(n):
                run(i)
            walls.append(time.perf_counter() - wall)
            cpus.append(time.process_time() - cpu)
        finally:
            gc.enable()
    return min(walls) / n, min(cpus) / n


def side_by_side(ours: Callable[[int], object], theirs: Callable[[int], object], n: int, passes: int) -> np.ndarray:
    """Per pass, the wall and CPU seconds per utterance of ``ours`` and ``theirs`` run one after the
    other on each utterance (passes × [our wall, our CPU, their wall, their CPU]): a busy machine
    slows both alike."""
    totals = np.zeros((passes, 4))
    for k in range(passes):
        gc.collect()
        gc.disable()
        try:
            for i in range(n):
                for j, run in ((0, ours), (2, theirs)):
                    wall, cpu = time.perf_counter(), time.process_time()
                    run(i)
                    totals[k, j] += time.perf_counter() - wall
                    totals[k, j + 1] += time.process_time() - cpu
        finally:
            gc.enable()
    return totals / n


def vispeech_path(paths: list[Path], out: Path, fps: float) -> Stages:
    """vispeech's path over ``paths``, writing under ``out``, warmed up."""
    model = load_model(MODEL)
    config = PostprocessConfig.from_preset(model.postprocessing)
    phones = [read_alignment(p) for p in paths]
    raw = [model.predict(p, fps) for p in phones]
    tracks = [postprocess(t, p, config) for t, p in zip(raw, phones)]
    folders = [out / p.stem for p in paths]

    def whole(i: int) -> None:
        sequence = read_alignment(paths[i])
        track = animate(sequence, model, fps)
        write_outputs(Utterance(phones=sequence, track=track), folders[i], formats=("livelink",))

    for i in range(len(paths)):  # untimed: the first calls of a process run slower (page faults, caches)
        whole(i)
    return {
        "read": lambda i: read_alignment(paths[i]),
        "model": lambda i: model.predict(phones[i], fps),
        "post-processing": lambda i: postprocess(raw[i], phones[i], config),
        "write": lambda i: write_outputs(Utterance(phones=phones[i], track=tracks[i]), folders[i],
                                         formats=("livelink",)),
        "whole": whole,
    }


def openfacefx_path(paths: list[Path], out: Path, fps: float) -> Stages | None:
    """OpenFaceFX's path over ``paths``, writing under ``out``, warmed up; ``None`` without it."""
    try:
        from openfacefx import generate_from_alignment, load_mfa_textgrid, retarget, write_livelink_csv
        from openfacefx.retarget import PRESETS
    except ImportError:
        return None
    arkit = PRESETS["arkit"]
    names = [str(p) for p in paths]
    files = [str(out / f"{p.stem}.csv") for p in paths]
    segments = [load_mfa_textgrid(p) for p in names]
    tracks = [retarget(generate_from_alignment(s, fps=fps), arkit) for s in segments]

    def whole(i: int) -> None:
        track = retarget(generate_from_alignment(load_mfa_textgrid(names[i]), fps=fps), arkit)
        write_livelink_csv(track, files[i], fps=fps)

    for i in range(len(paths)):
        whole(i)
    return {
        "read": lambda i: load_mfa_textgrid(names[i]),
        "model": lambda i: retarget(generate_from_alignment(segments[i], fps=fps), arkit),
        "write": lambda i: write_livelink_csv(tracks[i], files[i], fps=fps),
        "whole": whole,
    }


def ms(seconds: tuple[float, float]) -> str:
    """Wall and CPU seconds as two columns of milliseconds."""
    return f"{1e3 * seconds[0]:8.3f} {1e3 * seconds[1]:8.3f}"


def report(ours: Stages, theirs: Stages | None, n: int, passes: int) -> None:
    """Print each stage's times, then the whole paths' side by side and their ratios."""
    print(f"{'ms per utterance':<18} {'vispeech':>17} {'OpenFaceFX':>17}")
    print(f"{'':<18} {'wall':>8} {'CPU':>8} {'wall':>8} {'CPU':>8}")
    for stage in ("read", "model", "post-processing", "write", "whole"):
        other = "" if theirs is None or stage not in theirs else ms(best_pass(theirs[stage], n, passes))
        print(f"{stage:<18} {ms(best_pass(ours[stage], n, passes))} {other}")
    print("(OpenFaceFX's model row is its curves and retargeting; vispeech's read row includes its checks)")
    if theirs is None:
        print("OpenFaceFX is not installed (pip install openfacefx): no ratio")
        return
    times = side_by_side(ours["whole"], theirs["whole"], n, passes)
    best = times.min(axis=0)
    print(f"whole paths side by side, best of {passes} passes: vispeech {ms(best[:2])}, OpenFaceFX {ms(best[2:])}")
    for kind, k in (("wall", 0), ("CPU", 1)):
        ratios = times[:, k + 2] / times[:, k]
        verdict = "met" if np.median(ratios) >= TARGET else "NOT met"
        print(f"OpenFaceFX / vispeech, {kind} time: {np.median(ratios):.1f}x (passes {ratios.min():.1f}x to "
              f"{ratios.max():.1f}x; target {TARGET:g}x: {verdict})")
    print("(CPU time leaves out waits: vispeech's fsyncs, and other processes on a busy machine)")


def keep(paths: list[Path], folder: Path, fps: float) -> None:
    """vispeech's CSV folders and its tracks (``tracks.npz``) for ``paths``, written into ``folder``."""
    model = load_model(MODEL)
    folder.mkdir(parents=True, exist_ok=True)
    tracks = {}
    for path in paths:
        phones = read_alignment(path)
        track = animate(phones, model, fps)
        write_outputs(Utterance(phones=phones, track=track), folder / path.stem, formats=("livelink",))
        tracks[path.stem] = track.values
        tracks[f"{path.stem}/channels"] = np.array(track.channels)
    np.savez(folder / "tracks.npz", **tracks)


def profile(paths: list[Path], out: Path, fps: float) -> None:
    """cProfile of vispeech's whole path over ``paths``: the 30 functions of most own time."""
    import cProfile
    import pstats

    model = load_model(MODEL)

    def run() -> None:
        for path in paths:
            phones = read_alignment(path)
            track = animate(phones, model, fps)
            write_outputs(Utterance(phones=phones, track=track), out / path.stem, formats=("livelink",))

    run()
    profiler = cProfile.Profile()
    profiler.runcall(run)
    pstats.Stats(profiler).sort_stats("tottime").print_stats(30)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--utterances", type=int, default=100)
    parser.add_argument("--fps", type=float, default=30.0, help="Frames per second of both tools' CSVs.")
    parser.add_argument("--passes", type=int, default=5, help="Passes per stage; the best counts.")
    parser.add_argument("--out", type=Path, default=None, help="Folder for the output folders [default: temporary].")
    parser.add_argument("--keep", type=Path, default=None, help="Keep vispeech's CSVs and tracks in this folder.")
    parser.add_argument("--profile", action="store_true", help="Print the cProfile of vispeech's path.")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_phones_", dir=args.out) as tmp:
        root = Path(tmp)
        (root / "grids").mkdir()
        (root / "vispeech").mkdir()
        (root / "openfacefx").mkdir()
        paths = held_out_textgrids(root / "grids", args.utterances)
        print(f"{len(paths)} held-out grid_s1 utterances as TextGrids, {args.fps:g} fps, "
              f"best of {args.passes} passes, output under {root}")
        if args.keep is not None:
            shutil.rmtree(args.keep, ignore_errors=True)
            keep(paths, args.keep, args.fps)
            print(f"kept vispeech's CSVs and tracks in {args.keep}")
        if args.profile:
            profile(paths, root / "vispeech", args.fps)
            return
        ours = vispeech_path(paths, root / "vispeech", args.fps)
        theirs = openfacefx_path(paths, root / "openfacefx", args.fps)
        report(ours, theirs, len(paths), args.passes)


if __name__ == "__main__":
    main()
