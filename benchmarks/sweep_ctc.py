"""The λ_CTC sweep of an audio network on GRID speaker 1: jawOpen r against the CTC weight.

    python benchmarks/sweep_ctc.py [--family audio-cnn] [--weights 0 0.001 0.004 0.016 0.064]
                                   [--epochs 15] [--channels 64] [--train 200] [--seeds 0 1]
                                   [--output docs/figures/ctc_sweep] [--save DIR]

Trains networks per CTC weight (the shipped architecture of ``--family`` from
``train_default.ARCHITECTURES`` with the CTC weight replaced, the epoch budget capped and,
to fit a sweep on two cores, optionally ``--channels`` per layer, the first ``--train``
training utterances and no pitch-shifted copies; one network per seed, scores averaged),
scores each on the validation and test splits (audio alone, post-processed as `vispeech
evaluate` does), and writes ``OUTPUT.csv`` and the plot ``OUTPUT.png`` / ``OUTPUT.svg``
(PhISANet's Table 4.5 / 5.4 as a figure). The weight is chosen on validation; test is reported.
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from vispeech.corpus import CorpusWarning, align_corpus, read_grid
from vispeech.evaluation import evaluate_models
from vispeech.models.fitting import Splits
from vispeech.models.registry import create_model, family_class

sys.path.insert(0, str(Path(__file__).parent))
from train_default import ARCHITECTURES, ROOT  # noqa: E402

SHIPPED = {"audio-cnn": "grid-audio-cnn", "audio-encdec": "grid-audio-encdec"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--family", default="audio-cnn", choices=sorted(SHIPPED))
    parser.add_argument("--weights", type=float, nargs="+", default=[0.0, 0.001, 0.004, 0.016, 0.064])
    parser.add_argument("--epochs", type=int, default=15)
    parser.add_argument("--corpus", type=Path, default=ROOT.parent / "shared" / "data" / "grid_s1")
    parser.add_argument("--output", type=Path, default=ROOT / "docs" / "figures" / "ctc_sweep")
    parser.add_argument("--channels", type=int, default=None, help="channels per layer [default: the shipped]")
    parser.add_argument("--train", type=int, default=None, help="training utterances [default: all]")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--save", type=Path, default=None,
                        help="keep each network in SAVE/ctc-WEIGHT-seed-SEED (for vispeech evaluate)")
    args = parser.parse_args()

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CorpusWarning)
        corpus = read_grid(args.corpus)
        align_corpus(corpus)
    family, params = ARCHITECTURES[SHIPPED[args.family]]
    params = {**params, "epochs": args.epochs}
    if args.channels:
        params["channels"] = [args.channels] * len(family_defaults(family)["channels"])
    training = Splits(corpus.split("train")[: args.train], corpus.split("validation"))
    if args.train:
        params["pitch_copies"] = 0
    rows = []
    for weight in args.weights:
        start = time.perf_counter()
        scores: dict[str, list[float]] = {}
        for seed in args.seeds:
            model = create_model(family, **{**params, "ctc_weight": weight, "seed": seed})
            model.fit(training, progress=False, num_threads=args.threads)
            if args.save is not None:
                name = f"{family}-ctc-{weight:g}-seed-{seed}"
                model.save(args.save / name, name=name)
            for split in ("validation", "test"):
                jaw = evaluate_models(corpus.split(split), {"m": model}, channels=["jawOpen"]).models[0].scores["jawOpen"]
                scores.setdefault(f"{split}_r", []).append(jaw["r"])
                scores.setdefault(f"{split}_rmse_percent", []).append(jaw["rmse_percent"])
        row = {"ctc_weight": weight, "seeds": len(args.seeds), "seconds": round(time.perf_counter() - start)}
        row |= {key: round(float(np.mean(values)), 4) for key, values in scores.items()}
        rows.append(row)
        print(row, flush=True)

    args.output.parent.mkdir(parents=True, exist_ok=True)
    with open(args.output.with_suffix(".csv"), "w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    setting = (f"{args.channels or 'shipped'} channels, {args.train or 'all'} training utterances, "
               f"{args.epochs} epochs, {len(args.seeds)} seed(s)")
    plot(rows, args.output, f"{args.family} on grid_s1 ({setting})")
    print(f"-> {args.output}.csv, .png, .svg")


def family_defaults(family: str) -> dict:
    return dict(family_class(family).defaults)


def plot(rows: list[dict], output: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    weights = [r["ctc_weight"] for r in rows]
    positions = range(len(weights))
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for split, style in (("validation", "o-"), ("test", "s--")):
        ax.plot(positions, [r[f"{split}_r"] for r in rows], style, label=split)
    ax.set_xticks(list(positions), [f"{w:g}" for w in weights])
    ax.set_xlabel("λ_CTC (CTC loss weight)")
    ax.set_ylabel("jawOpen Pearson r")
    ax.set_title(title + "\naudio alone, post-processed", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    for suffix in (".png", ".svg"):
        fig.savefig(output.with_suffix(suffix), dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    main()
