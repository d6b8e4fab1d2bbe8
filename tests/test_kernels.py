"""The NumPy inference path equals torch's forward pass on every shipped network (to 1e-5)."""

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import require_module

from vispeech.alignment.phones import PhoneSequence
from vispeech.models.networks.network import Network
from vispeech.models.registry import PRETRAINED, load_model

GOLDEN_PHONES = json.loads((Path(__file__).parent / "golden" / "phones.json").read_text(encoding="utf-8"))
NETWORKS = [name for name in PRETRAINED if isinstance(load_model(name), Network) and load_model(name).input_kind == "phones"]
"""The shipped phone networks (the audio networks' kernels are tested in tests/test_audio_networks.py)."""


def torch_outputs(model: Network, inputs: np.ndarray) -> np.ndarray:
    """The trained module's forward pass in float64 (what prediction ran on before the NumPy kernels)."""
    torch = require_module("torch", "torch (the train extra)")
    module = model._build_module(model.encoding_.size, len(model.outputs_))
    module.load_state_dict({k: torch.from_numpy(v.copy()) for k, v in model.weights_.items()})
    module = module.double().eval()
    p = model.get_params()
    padded = np.pad(inputs, ((p["look_back"], p["look_ahead"]), (0, 0)), mode="edge")
    with torch.no_grad():
        return module(torch.from_numpy(padded).double()[None])[0].numpy()


@pytest.mark.parametrize("name", NETWORKS)
def test_numpy_kernel_equals_torch(name):
    model = load_model(name)
    worst = 0.0
    for entry in GOLDEN_PHONES:
        phones = PhoneSequence.from_dict(entry)
        inputs = model.encoding_.encode(phones, model.fps_)
        light = model._denormalise(model.kernel.forward(inputs))
        reference = model._denormalise(torch_outputs(model, inputs))
        worst = max(worst, float(np.abs(light - reference).max()))
    assert worst <= 1e-5, f"{name}: largest difference {worst:.2e}"


@pytest.mark.parametrize("name", NETWORKS)
def test_frame_by_frame_step_equals_torch(name):
    """The kernel's one-frame step (what streams run: the drive from the frame's input window
    alone, then the recurrence) gives the same frames as torch offline."""
    model = load_model(name)
    phones = PhoneSequence.from_dict(GOLDEN_PHONES[3])
    inputs = model.encoding_.encode(phones, model.fps_)
    p = model.get_params()
    kernel, state, frames = model.kernel, model.kernel.initial_state(), []
    for t in range(len(inputs)):
        index = np.clip(np.arange(t - p["look_back"], t + p["look_ahead"] + 1), 0, len(inputs) - 1)
        drive = kernel.window_terms(inputs[index])[p["look_back"]]
        out, state = kernel.advance(drive[None], [s[None] for s in state])
        frames.append(out[0])
        state = [s[0] for s in state]
    reference = torch_outputs(model, inputs)
    np.testing.assert_allclose(model._denormalise(np.array(frames)), model._denormalise(reference), atol=1e-5)


@pytest.mark.parametrize("name", NETWORKS)
def test_several_streams_step_together_as_each_alone(name):
    """One recurrence step for several streams (what the server does for concurrent sessions),
    from the window terms' drives, gives each stream the frames it gets alone and what the whole
    sequence gives offline."""
    model = load_model(name)
    kernel = model.kernel
    inputs = [model.encoding_.encode(PhoneSequence.from_dict(entry), model.fps_) for entry in GOLDEN_PHONES[:4]]
    n = min(len(x) for x in inputs)
    drives = [kernel.window_terms(x) for x in inputs]

    states = [np.stack(parts) for parts in zip(*(kernel.initial_state() for _ in inputs))]
    together = []
    for t in range(n):
        out, states = kernel.advance(np.stack([d[t] for d in drives]), states)
        together.append(out)
    for b, x in enumerate(inputs):
        state, alone = [s[None] for s in kernel.initial_state()], []
        for t in range(n):
            out, state = kernel.advance(drives[b][t][None], state)
            alone.append(out[0])
        np.testing.assert_allclose(np.array(together)[:, b], np.array(alone), atol=1e-6)
        np.testing.assert_allclose(np.array(alone), kernel.forward(x)[:n], atol=1e-5)


@pytest.mark.parametrize("name", NETWORKS)
def test_utterances_run_together_get_the_bits_they_get_alone(name):
    """forward_many (one window-terms pass over all the utterances, the recurrence stepping them
    together) gives each utterance exactly its forward alone, whatever ran before: the window
    terms' cache empty or filled by other utterances, utterances of different lengths."""
    model = load_model(name)
    inputs = [model.encoding_.encode(PhoneSequence.from_dict(e), model.fps_) for e in GOLDEN_PHONES]
    together = model.kernel.forward_many(inputs[::-1])[::-1]
    kernel = load_model(name).kernel
    assert len({len(x) for x in inputs}) > 3
    for x, out in zip(inputs, together, strict=True):
        np.testing.assert_array_equal(out, kernel.forward(x))
    assert kernel.forward_many([]) == []


@pytest.mark.parametrize("family", ["sliding-window-thesis", "sliding-window-taylor"])
def test_window_kernel_equals_torch(family):
    """The sliding-window networks' NumPy forward pass equals their torch module's (overlap-averaged)."""
    torch = require_module("torch", "torch (the train extra)")
    from test_contract import TINY_NETWORKS, tiny_corpus

    from vispeech.models.networks.modules import edge_pad, overlap_average, windows
    from vispeech.models.registry import create_model

    model = create_model(family, epochs=2, targets=["jawOpen", "mouthPucker"],
                         **TINY_NETWORKS[family]).fit(tiny_corpus(), progress=False, num_threads=1)
    module = model._build_module(model.encoding_.size, len(model.outputs_))
    module.load_state_dict({k: torch.from_numpy(v.copy()) for k, v in model.weights_.items()})
    module = module.double().eval()
    p = model.get_params()
    for seed in (60, 61):
        inputs = model.encoding_.encode(tiny_corpus([seed])[0].phones, model.fps_)
        with torch.no_grad():
            padded = edge_pad(inputs, (p["input_window"] + p["output_window"]) // 2 - 1).double()
            reference = overlap_average(module(windows(padded, p["input_window"])), len(inputs)).numpy()
        np.testing.assert_allclose(model.kernel.forward(inputs), reference, atol=1e-9)


@pytest.mark.parametrize("bidirectional", [True, False])
def test_lstm_kernel_equals_torch(bidirectional):
    """Taylor's LSTM baseline: the NumPy forward pass equals the torch module's, with and without
    the backward direction, on an utterance it was not trained on."""
    torch = require_module("torch", "torch (the train extra)")
    from test_contract import TINY_NETWORKS, sentence, tiny_corpus

    from vispeech.models.registry import create_model

    model = create_model("lstm-taylor", **{**TINY_NETWORKS["lstm-taylor"], "bidirectional": bidirectional},
                         epochs=3, targets=["jawOpen", "mouthPucker"]).fit(tiny_corpus(), progress=False, num_threads=1)
    module = model._build_module(model.encoding_.size, len(model.outputs_))
    module.load_state_dict({k: torch.from_numpy(v.copy()) for k, v in model.weights_.items()})
    module.eval()
    inputs = model.encoding_.encode(sentence(70), model.fps_)
    with torch.no_grad():
        reference = module(torch.from_numpy(inputs[None]).float())[0].double().numpy()
    np.testing.assert_allclose(model.kernel.forward(inputs), reference, atol=1e-5)
    assert model.kernel.forward(inputs).shape == (len(inputs), 2)
