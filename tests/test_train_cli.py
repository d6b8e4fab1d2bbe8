"""``vispeech train`` on a tiny synthetic corpus of takes (phones from TextGrids, no aligner)."""

import json
import os

import numpy as np
import pytest
import soundfile
from click.testing import CliRunner

from vispeech import PhoneSequence, Track
from vispeech.alignment.formats import write_textgrid
from vispeech.alignment.phones import Phone, Word
from vispeech.cli import main
from vispeech.corpus import split_of
from vispeech.errors import VispeechError
from vispeech.models.networks.network import Network
from vispeech.models.registry import load_model
from vispeech.motion.formats.livelink import LIVELINK_CHANNELS, write_livelink_csv
from vispeech.phonetics.inventory import is_vowel

FPS = 25.0
WORDS = {"bin": "B IH N", "blue": "B L UW", "at": "AE T", "now": "N AW", "please": "P L IY Z", "may": "M EY"}
TAKE_IDS = [f"u{i:02d}" for i in range(20)]  # u00, u19 test; u18 validation; the rest train


def synthetic_take(seed: int) -> tuple[PhoneSequence, Track]:
    """Phones of four words (80 ms each, 0.3 s of silence around) and a track that follows them:
    jawOpen 0.35 on vowels, 0 on /p b m/, 0.1 elsewhere, lightly smoothed; mouthClose 0.02."""
    rng = np.random.default_rng(seed)
    chosen = rng.choice(list(WORDS), size=4)
    phones, words, t = [Phone("sil", 0.0, 0.3)], [], 0.3
    for w, word in enumerate(chosen):
        start = t
        for symbol in WORDS[word].split():
            phones.append(Phone(symbol, t, t + 0.08, w))
            t += 0.08
        words.append(Word(str(word), start, t))
    phones.append(Phone("sil", t, t + 0.3))
    sequence = PhoneSequence(phones, "en", words)
    labels = sequence.frame_labels(FPS, int(round(sequence.duration * FPS)))
    jaw = np.array([0.35 if is_vowel(s, "en") else 0.0 if s in ("P", "B", "M") else 0.1 for s in labels])
    jaw = np.convolve(np.pad(jaw, 1, mode="edge"), [0.25, 0.5, 0.25], mode="valid")
    values = np.zeros((len(labels), len(LIVELINK_CHANNELS)))
    values[:, LIVELINK_CHANNELS.index("jawOpen")] = jaw
    values[:, LIVELINK_CHANNELS.index("mouthClose")] = 0.02
    return sequence, Track(values, LIVELINK_CHANNELS, FPS)


def write_takes(folder, ids=TAKE_IDS):
    """A folder of Live Link takes (CSV, silent WAV, TextGrid) made by :func:`synthetic_take`."""
    folder.mkdir(parents=True, exist_ok=True)
    for i, name in enumerate(ids):
        phones, track = synthetic_take(i)
        write_livelink_csv(track, folder / f"{name}.csv")
        soundfile.write(folder / f"{name}.wav", np.zeros(int(phones.duration * 16000), dtype=np.float32), 16000)
        write_textgrid(phones, folder / f"{name}.TextGrid")
    return folder


@pytest.fixture(autouse=True)
def cache_home(tmp_path, monkeypatch):
    monkeypatch.setenv("VISPEECH_CACHE", str(tmp_path / "cache-home"))


@pytest.fixture(scope="module")
def takes(tmp_path_factory):
    return write_takes(tmp_path_factory.mktemp("corpus") / "takes")


def test_split_layout_of_the_synthetic_ids():
    splits = [split_of(i) for i in TAKE_IDS]
    assert splits.count("test") == 2 and splits.count("validation") == 1


def _train(*args):
    return CliRunner().invoke(main, ["train", *map(str, args)])


def test_train_saves_a_model_and_reports_test_scores(takes, tmp_path):
    out = tmp_path / "my-thesis"
    result = _train("--corpus", takes, "--language", "en", "--model", "sliding-window-thesis",
                    "--epochs", "2", "--seed", "3", "--quiet", "-o", out)
    assert result.exit_code == 0, result.output
    assert "train 17, validation 1, test 2 utterances at 25 fps" in result.output
    assert "epochs: 2, best" in result.output
    assert "test split (2 utterances, no post-processing): jawOpen r " in result.output
    assert (out / "loss_curve.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not (out / "checkpoint").exists()
    assert {p.name for p in out.iterdir()} == {"config.json", "weights.safetensors", "loss_curve.png"}
    model = load_model(out)
    assert model.name == "my-thesis" and model.family == "sliding-window-thesis"
    assert model.is_fitted and model.history_.epochs == 2 and model.postprocessing == "learned-jaw"
    assert model.get_params()["seed"] == 3 and model.get_params()["epochs"] == 2
    assert "progress" not in model.get_params()
    assert "checkpoint_dir" not in model.get_params() and "checkpoint_dir" not in (out / "config.json").read_text()


def test_interrupted_run_resumes_from_its_checkpoint(takes, tmp_path, monkeypatch):
    out = tmp_path / "model"

    save = Network.save

    def fail(self, path, **options):  # the checkpoints after every epoch are written, the model at the end is not
        if path != out / "checkpoint":
            raise VispeechError("disk full")
        return save(self, path, **options)

    monkeypatch.setattr(Network, "save", fail)
    result = _train("--corpus", takes, "--language", "en", "-m", "sliding-window-thesis", "--epochs", "1",
                    "-p", "learning_rate=0.002", "-q", "-o", out)
    assert result.exit_code == 2 and "error: disk full" in result.output
    assert not (out / "config.json").exists()
    assert (out / "checkpoint" / "training_state.json").is_file()
    first = json.loads((out / "checkpoint" / "config.json").read_text())["state"]["history"]["train_loss"]
    assert len(first) == 1
    monkeypatch.undo()

    result = _train("--corpus", takes, "--language", "en", "-m", "sliding-window-thesis", "--epochs", "2",
                    "-q", "--resume", out, "-o", out)  # its learning rate need not be given again
    assert result.exit_code == 0, result.output
    config = json.loads((out / "config.json").read_text())
    assert config["params"]["learning_rate"] == 0.002 and config["params"]["epochs"] == 2
    assert config["name"] == "model" and len(config["state"]["history"]["train_loss"]) == 2
    assert config["state"]["history"]["train_loss"][0] == first[0]  # went on, did not start over
    assert not (out / "checkpoint").exists()


def test_train_targets_articulatory_needs_landmarks(takes, tmp_path):
    result = _train("--corpus", takes, "--language", "en", "-m", "tdnn-beskow", "--targets", "articulatory",
                    "--epochs", "1", "-q", "-o", tmp_path / "m")
    assert result.exit_code == 2 and "no face landmarks" in result.output


@pytest.mark.parametrize(("args", "message"), [
    (["--corpus", "{missing}", "-m", "sliding-window-thesis"], "corpus folder not found"),
    (["--corpus", "{empty}", "-m", "sliding-window-thesis"], "holds no takes"),
    (["--corpus", "{takes}", "-m", "nonesuch"],
     "unknown model family 'nonesuch' (train one of: audio-cnn, audio-encdec, cohen-massaro, ohman, "),
    (["--corpus", "{takes}", "-m", "grid-tdnn"], "unknown model family 'grid-tdnn'"),
    (["--corpus", "{takes}", "-m", "baseline"], "model baseline is data-free"),
    (["--corpus", "{takes}", "-m", "audio-ensemble"], "model audio-ensemble learns nothing itself"),
    (["--corpus", "{takes}", "-m", "cohen-massaro", "--epochs", "3"], "model cohen-massaro takes no --epochs"),
    (["--corpus", "{takes}", "-m", "ohman", "--resume", "{takes}"], "--resume needs a network"),
])
def test_train_errors_are_one_line(takes, tmp_path, args, message):
    (tmp_path / "empty").mkdir()
    places = {"missing": tmp_path / "missing", "empty": tmp_path / "empty", "takes": takes}
    args = [a.format(**places) for a in args]
    result = _train(*args, "--language", "en", "-q", "-o", tmp_path / "out")
    assert result.exit_code == 2
    assert result.output.startswith("error: ") and message in result.output
    assert "baseline" not in result.output or "baseline is data-free" in result.output  # only what trains is offered
    assert not (tmp_path / "out" / "config.json").exists()


def test_an_output_folder_that_cannot_be_replaced_is_refused_before_training(takes, tmp_path):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep")
    result = _train("--corpus", takes, "-m", "tdnn-beskow", "--epochs", "1", "-p", "hidden=4", "--language", "en",
                    "-q", "-o", tmp_path / "mine")
    assert result.exit_code == 2 and "holds files vispeech did not write (notes.txt)" in result.output
    assert "saved" not in result.output and os.listdir(tmp_path / "mine") == ["notes.txt"]  # no checkpoint left


def test_train_from_a_shipped_network_adapts_it(takes, tmp_path):
    """``--from grid-tdnn``: the shipped network warm-started on a new speaker's takes, scored
    before and after, saved and loaded as any model (issue 13, part 5)."""
    import numpy as np

    from vispeech.alignment.formats import read_alignment

    out = tmp_path / "adapted"
    result = _train("--corpus", takes, "--language", "en", "--from", "grid-tdnn", "--epochs", "2", "--quiet", "-o", out)
    assert result.exit_code == 0, result.output
    assert "adapting grid-tdnn on 17 utterances" in result.output
    assert result.output.count("test split (2 utterances, no post-processing): jawOpen r ") == 2  # before, after
    adapted, base = load_model(out), load_model("grid-tdnn")
    assert adapted.family == base.family and adapted.history_.epochs == 2 and adapted.name == "adapted"
    assert not {"warm_start", "checkpoint_dir"} & set(adapted.get_params())  # run settings, not parameters
    phones = read_alignment(next(takes.glob("*.TextGrid")))
    moved = np.abs(adapted.predict(phones, 25.0).values - base.predict(phones, 25.0).values).max()
    assert 0 < moved < 0.5  # it started from grid-tdnn's weights and learned from the takes


@pytest.mark.parametrize(("args", "message"), [
    (["--from", "grid-tdnn", "-m", "tdnn-beskow"], "give --model FAMILY to train one afresh, or --from MODEL"),
    (["--from", "baseline"], "--from needs a trained network (phones or audio); 'baseline' is a baseline model"),
    (["--from", "grid-tdnn", "--input", "phones"], "--from keeps the model's inputs and targets"),
    (["--from", "grid-tdnn", "-p", "warm_start=false"], "takes no parameter 'warm_start'"),
])
def test_train_from_errors_are_one_line(takes, tmp_path, args, message):
    result = _train("--corpus", takes, "--language", "en", *args, "-o", tmp_path / "out")
    assert result.exit_code == 2 and message in result.output, result.output
