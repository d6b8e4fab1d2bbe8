"""glTF 2.0 animation: a morph-target ``weights`` animation added to a copy of a GLB model.

The model is read as :mod:`vispeech.motion.rigging.glb` reads it (ARKit-named morph targets);
its binary data is kept byte for byte, meshoptimizer-compressed data compressed (or decoded
on request, for Blender, Maya and other importers without that extension), and the animation
appended uncompressed.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
import pygltflib

from vispeech.errors import UnshownChannelsWarning, VispeechError
from vispeech.files import atomic_output_file
from vispeech.motion.rigging.glb import animated_meshes, append_accessor, decompressed, embedded_glb, glb_bytes
from vispeech.motion.track import Track


def write_gltf_animation(
    track: Track,
    base_glb: str | os.PathLike,
    out_path: str | os.PathLike,
    name: str = "speech",
    *,
    uncompressed: bool = False,
) -> None:
    """Write a copy of ``base_glb`` with ``track`` added as the animation ``name``.

    Every node whose mesh has ARKit-named morph targets gets one ``weights`` channel with a
    LINEAR sampler: input times ``k / fps`` seconds (k = 0 .. n_frames-1, from the track's
    first frame), output the weights of all the mesh's targets in target order for each frame
    (targets with no ARKit name, or a channel the track lacks, stay 0). The model's
    ``EXT_meshopt_compression`` data stays compressed unless ``uncompressed``, which decodes
    it into one plain buffer. Written atomically; the track's channels that no morph target
    shows are named in one :class:`UnshownChannelsWarning`.
    """
    gltf = embedded_glb(base_glb)
    try:
        meshes = animated_meshes(gltf)
        nodes = [(i, node.mesh) for i, node in enumerate(gltf.nodes) if node.mesh in meshes]
    except (AttributeError, TypeError, ValueError, KeyError, IndexError):
        raise VispeechError(f"{base_glb}: malformed glTF meshes or nodes") from None
    if not meshes:
        raise VispeechError(f"{base_glb} has no mesh with ARKit-named morph targets (mesh.extras.targetNames)")
    if not nodes:
        raise VispeechError(f"{base_glb}: no node uses the meshes with ARKit-named morph targets")

    blob = bytearray(decompressed(gltf, base_glb) if uncompressed else gltf.binary_blob() or b"")
    times = (np.arange(track.n_frames) / track.fps).astype(np.float32)
    time_accessor = append_accessor(gltf, blob, times)
    outputs: dict[int, int] = {}
    animation = pygltflib.Animation(name=name, channels=[], samplers=[])
    for node, mesh in nodes:
        if mesh not in outputs:
            names = meshes[mesh]
            weights = np.zeros((track.n_frames, len(names)), dtype=np.float32)
            for j, arkit in enumerate(names):
                if arkit is not None and arkit in track.channels:
                    weights[:, j] = track[arkit]
            outputs[mesh] = append_accessor(gltf, blob, weights.reshape(-1))
        animation.samplers.append(
            pygltflib.AnimationSampler(input=time_accessor, output=outputs[mesh], interpolation="LINEAR")
        )
        animation.channels.append(
            pygltflib.AnimationChannel(
                sampler=len(animation.samplers) - 1, target=pygltflib.AnimationChannelTarget(node=node, path="weights")
            )
        )
    gltf.animations.append(animation)
    with atomic_output_file(out_path) as tmp:
        tmp.write_bytes(glb_bytes(gltf, blob))
    shown = {channel for names in meshes.values() for channel in names}
    unshown = [channel for channel in track.channels if channel not in shown]
    if unshown:
        warnings.warn(
            f"{Path(base_glb).name} has no morph target for {len(unshown)} of the track's channels, "
            f"which are left out: {', '.join(unshown)}",
            UnshownChannelsWarning,
            stacklevel=2,
        )
