"""Run by Blender (``blender -b --python read_scene.py -- IN.glb|IN.fbx OUT.json``): import a glTF
or FBX file as Blender's own importers do and write what arrived as JSON: each object's type,
its shape keys and the keyframes (frame, value) of every F-curve of its shape-key action, and
the scene's frame rate."""

import json
import sys

import numpy

numpy.bool = bool  # Blender 3.4's glTF importer still uses the alias that numpy 1.24 removed

import bpy  # noqa: E402

glb, out = sys.argv[sys.argv.index("--") + 1:]
bpy.ops.wm.read_factory_settings(use_empty=True)
if glb.lower().endswith(".fbx"):
    bpy.ops.import_scene.fbx(filepath=glb)
else:
    bpy.ops.import_scene.gltf(filepath=glb)
found = {"fps": bpy.context.scene.render.fps / bpy.context.scene.render.fps_base, "objects": []}
for obj in bpy.data.objects:
    item = {"name": obj.name, "type": obj.type, "shape_keys": [], "fcurves": {}}
    keys = obj.data.shape_keys if obj.type == "MESH" else None
    if keys is not None:
        item["shape_keys"] = [block.name for block in keys.key_blocks]
        action = keys.animation_data.action if keys.animation_data else None
        if action is not None:
            item["fcurves"] = {curve.data_path: [list(point.co) for point in curve.keyframe_points]
                               for curve in action.fcurves}
    found["objects"].append(item)
with open(out, "w", encoding="utf-8") as f:
    json.dump(found, f)
