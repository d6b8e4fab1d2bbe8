"""The audio ensemble: the weighted mean of audio networks' frames and CTC posteriors, saved by name."""

import json

import numpy as np
import pytest

pytest.importorskip("torch")

from test_audio_networks import TINY, clip_of, synthetic_utterance  # noqa: E402

from vispeech import VispeechError  # noqa: E402
from vispeech.models.fitting import Splits  # noqa: E402
from vispeech.models.networks.audio import AudioCNNNetwork, EncoderDecoderNetwork  # noqa: E402
from vispeech.models.ensemble import AudioEnsemble  # noqa: E402
from vispeech.models.networks.phone_head import heard_bilabials  # noqa: E402
from vispeech.models.registry import create_model, load_model  # noqa: E402


@pytest.fixture(scope="module")
def members(tmp_path_factory) -> dict[str, str]:
    """Folders of tiny networks on the same synthetic corpus: two that hear bilabials with CTC heads
    over the same phones (an encoder-decoder and a CNN, at closure_threshold 1e-3), that CNN
    deaf (its head unused, at 0) and a CNN without a head."""
    rng = np.random.default_rng(0)
    corpus = Splits([synthetic_utterance(rng, i) for i in range(8)], [synthetic_utterance(rng, 50)])
    root = tmp_path_factory.mktemp("members")
    hearing = {"ctc_weight": 0.01, "closure_threshold": 1e-3}
    networks = {
        "encdec": EncoderDecoderNetwork(**{**TINY, "epochs": 6}, channels=[16, 16], hidden=8, **hearing),
        "cnn-head": AudioCNNNetwork(**{**TINY, "epochs": 6}, channels=[16, 16, 16], **hearing),
        "cnn": AudioCNNNetwork(**{**TINY, "epochs": 6}, channels=[16, 16, 16]),
    }
    folders = {name: str(network.fit(corpus, progress=False).save(root / name)) for name, network in networks.items()}
    deaf = networks["cnn-head"].set_params(closure_threshold=0.0).save(root / "cnn-head-deaf")
    return {**folders, "cnn-head-deaf": str(deaf)}


@pytest.fixture(scope="module")
def clip():
    return clip_of(synthetic_utterance(np.random.default_rng(1), 100))


def test_an_ensemble_is_the_weighted_mean_of_its_members(members, clip):
    a, b = load_model(members["encdec"]), load_model(members["cnn-head"])
    ensemble = AudioEnsemble(members=[members["encdec"], members["cnn-head"]], weights=[1, 3])
    assert ensemble.is_fitted and ensemble.input_kind == "audio" and ensemble.postprocessing == "audio"
    assert ensemble.channels == a.channels and ensemble.frame_rate == 50.0
    assert ensemble.lookahead == max(a.lookahead, b.lookahead)
    np.testing.assert_allclose(ensemble.weights, [0.25, 0.75])
    for fps in (25.0, 30.0):
        track = ensemble.predict(clip, fps)
        assert track.n_frames == clip.n_frames(fps) and track.channels == a.channels
        x, y = a.predict(clip, fps).values, b.predict(clip, fps).values
        mean = 0.25 * x + 0.75 * y
        assert np.all((track.values >= 0) & (track.values <= 1))
        for j in range(len(a.channels)):  # the mean, moving as far as the members do on the whole
            if 0 < track.values[:, j].min() and track.values[:, j].max() < 1:  # not clipped
                assert np.corrcoef(track.values[:, j], mean[:, j])[0, 1] > 1 - 1e-9
                assert track.values[:, j].mean() == pytest.approx(mean[:, j].mean(), abs=1e-12)
                assert track.values[:, j].std() == pytest.approx(0.25 * x[:, j].std() + 0.75 * y[:, j].std(), rel=1e-9)
        assert mean.std(axis=0).sum() < track.values.std(axis=0).sum()  # unlike the plain mean
        assert not np.allclose(track.values, x, atol=1e-3)  # both members count


def test_an_ensemble_hears_bilabials_in_its_members_mean_posteriors(members, clip):
    a, b = (load_model(members[name]) for name in ("encdec", "cnn-head"))
    ensemble = AudioEnsemble(members=[members["encdec"], members["cnn-head"]], closure_threshold=1e-3)
    track, heard = ensemble.predict_with_closures(clip, 25)
    posteriors = 0.5 * a.predict_with_posteriors(clip, 25)[1] + 0.5 * b.predict_with_posteriors(clip, 25)[1]
    expected = heard_bilabials(posteriors, a.phones_, "en", 50.0, 1e-3, 0.08)
    assert [(p.symbol, p.start, p.end) for p in heard] == [(p.symbol, p.start, p.end) for p in expected]
    assert any(p.symbol in ("B", "M", "P") for p in heard)
    np.testing.assert_array_equal(track.values, ensemble.predict(clip, 25).values)
    # an ensemble of one network twice hears what the network hears at the same threshold
    alone = [(p.symbol, p.start) for p in a.predict_with_closures(clip, 25)[1]]
    twice = AudioEnsemble(members=[members["encdec"]] * 2, closure_threshold=1e-3)
    assert [(p.symbol, p.start) for p in twice.predict_with_closures(clip, 25)[1]] == alone
    # a member whose head does not hear alone (closure_threshold 0) adds its frames, not its posteriors
    with_deaf = AudioEnsemble(members=[members["encdec"], members["cnn-head-deaf"]], closure_threshold=1e-3)
    track, heard = with_deaf.predict_with_closures(clip, 25)
    assert [(p.symbol, p.start) for p in heard] == alone
    deaf = load_model(members["cnn-head-deaf"])
    mean = 0.5 * (a.predict(clip, 25).values + deaf.predict(clip, 25).values)
    assert np.corrcoef(track["jawOpen"], mean[:, 0])[0, 1] > 0.9999  # (but where clipped to [0, 1])
    assert AudioEnsemble(members=[members["encdec"], members["cnn-head"]]).predict_with_closures(clip, 25)[1] is None


def test_a_saved_ensemble_keeps_its_members_names_and_predicts_alike(members, clip, tmp_path):
    ensemble = AudioEnsemble(members=[members["encdec"], members["cnn-head"]], weights=[2, 1])
    folder = ensemble.save(tmp_path / "ensemble", name="my-ensemble")
    config = json.loads((folder / "config.json").read_text())
    assert config["family"] == "audio-ensemble" and config["state"] is None and config["arrays"] == []
    assert config["params"]["members"] == [members["encdec"], members["cnn-head"]]
    assert sorted(p.name for p in folder.iterdir()) == ["config.json"]  # the members' weights stay theirs
    loaded = load_model(folder)
    assert type(loaded) is AudioEnsemble and loaded.name == "my-ensemble"
    np.testing.assert_array_equal(loaded.predict(clip, 30).values, ensemble.predict(clip, 30).values)


def test_an_ensemble_refuses_what_it_cannot_average(members, clip):
    with pytest.raises(VispeechError, match="two or more"):
        AudioEnsemble(members=[members["encdec"]])
    with pytest.raises(VispeechError, match="weights must be 2 positive numbers"):
        AudioEnsemble(members=[members["encdec"], members["cnn"]], weights=[1, 0])
    with pytest.raises(VispeechError, match="weights must be 2"):
        AudioEnsemble(members=[members["encdec"], members["cnn"]], weights=[1])
    with pytest.raises(VispeechError, match="grid-tdnn is a tdnn-beskow model: an audio ensemble takes audio networks"):
        AudioEnsemble(members=[members["encdec"], "grid-tdnn"])
    with pytest.raises(VispeechError, match="unknown model"):
        AudioEnsemble(members=[members["encdec"], "no-such-model"])
    with pytest.raises(VispeechError, match="only when some members do"):  # neither hears alone
        AudioEnsemble(members=[members["cnn-head-deaf"], members["cnn"]], closure_threshold=0.01)
    ensemble = AudioEnsemble(members=[members["encdec"], members["cnn"]])
    with pytest.raises(VispeechError, match=r"closure_threshold must be a number in \[0, 1\), got -1"):
        ensemble.set_params(closure_threshold=-1)
    with pytest.raises(VispeechError, match="closure_length must lie in"):
        ensemble.set_params(closure_length=0)
    assert ensemble.get_params()["closure_threshold"] == 0.0  # left as it was
    with pytest.raises(VispeechError, match="does not stream"):
        ensemble.stream(None, 30)
    with pytest.raises(VispeechError, match="learns nothing itself"):
        ensemble.fit([], progress=False)
    with pytest.raises(VispeechError, match="has no members"):
        create_model("audio-ensemble").predict(clip, 25)
    with pytest.raises(VispeechError, match="audio-ensemble learns nothing itself: give its parameters"):
        load_model("audio-ensemble")


def test_a_member_retrained_in_its_folder_changes_the_ensemble_s_version(members, tmp_path):
    """A batch and the server key an ensemble's outputs by its version: it must follow its members'
    files, which its own folder does not hold."""
    import shutil

    from vispeech.models.registry import model_version

    member = tmp_path / "member"
    shutil.copytree(members["encdec"], member)
    folder = AudioEnsemble(members=[str(member), members["cnn"]]).save(tmp_path / "ensemble")
    before = model_version(load_model(folder), folder)
    assert model_version(load_model(folder), folder) == before  # the same files: the same version
    shutil.rmtree(member)
    shutil.copytree(members["cnn-head"], member)  # another network trained into the member's folder
    assert model_version(load_model(folder), folder) != before
