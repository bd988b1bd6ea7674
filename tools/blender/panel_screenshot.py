# The add-on's sidebar panel, for the docs: Blender with a window (under Xvfb), the add-on installed
# from its zip, a generation started from the panel; screenshots 20 s into the run and after the
# import. Driven from outside (docs/blender.md "Screenshots"): Blender's 3.4 Python cannot pick a
# sidebar tab, so the driver clicks the "matlaber" tab once this script writes OUT/ready, and writes
# OUT/clicked to start the run.
#   blender --factory-startup --python panel_screenshot.py -- MATLABER ADDON_ZIP OUT [checks]
# With "checks" nothing starts by itself: the driver clicks the panel's buttons, and asks through files
# in OUT: set.json ({"prompt": "", "extra": "..."}: the fields set), shot_NAME (NAME.png taken and
# NAME.json written: the status, the error, whether a run is going, the run folders, and whether
# Generate, Paint and Resume are enabled), quit.
import json
import os
import sys
import time

import bpy

argv = sys.argv[sys.argv.index("--") + 1:]
binary, zip_path, out = argv[0], argv[1], argv[2]
checks = argv[3:4] == ["checks"]
bpy.ops.preferences.addon_install(filepath=zip_path)
bpy.ops.preferences.addon_enable(module="matlaber_blender")
prefs = bpy.context.preferences.addons["matlaber_blender"].preferences
prefs.binary = binary
prefs.runs_dir = os.path.join(out, "runs")
for o in list(bpy.data.objects):
    if o.type == "MESH":
        bpy.data.objects.remove(o)
settings = bpy.context.scene.matlaber
settings.prompt = "a gold goblet"
window = bpy.context.window_manager.windows[0]
area = next(a for a in window.screen.areas if a.type == "VIEW_3D")
area.spaces[0].show_region_ui = True
state = {"t0": time.time(), "started": None, "mid": False}


def shot(name):
    with bpy.context.temp_override(window=window, area=area):
        bpy.ops.screen.screenshot(filepath=os.path.join(out, name))


def operator_enabled(op):
    region = next(r for r in area.regions if r.type == "UI")
    with bpy.context.temp_override(window=window, area=area, region=region):
        return op.poll()


def check_tick():
    addon = sys.modules["matlaber_blender"]
    if time.time() - state["t0"] > 3:
        open(os.path.join(out, "ready"), "w").close()
    path = os.path.join(out, "set.json")
    if os.path.exists(path):
        with open(path) as f:
            for key, value in json.load(f).items():
                setattr(settings, key, value)
        os.remove(path)
    for name in sorted(os.listdir(out)):
        if name.startswith("shot_"):
            shot(name[5:] + ".png")
            runs = prefs.runs_dir
            state_now = {"prompt": settings.prompt, "status": settings.status, "error": settings.error,
                         "running": addon.job() is not None,
                         "runs": sorted(os.listdir(runs)) if os.path.isdir(runs) else [],
                         "generate_enabled": operator_enabled(bpy.ops.matlaber.generate),
                         "paint_enabled": operator_enabled(bpy.ops.matlaber.paint_selected),
                         "resume_enabled": operator_enabled(bpy.ops.matlaber.resume)}
            with open(os.path.join(out, name[5:] + ".json"), "w") as f:
                json.dump(state_now, f, indent=1)
            os.remove(os.path.join(out, name))
    if os.path.exists(os.path.join(out, "quit")) or time.time() - state["t0"] > 900:
        bpy.ops.wm.quit_blender()
        return None
    return 0.25


def tick():
    if state["started"] is None:
        if time.time() - state["t0"] > 3:
            open(os.path.join(out, "ready"), "w").close()
        if os.path.exists(os.path.join(out, "clicked")):
            region = next(r for r in area.regions if r.type == "WINDOW")
            with bpy.context.temp_override(window=window, area=area, region=region):
                bpy.ops.matlaber.generate()
            state["started"] = time.time()
        elif time.time() - state["t0"] > 120:
            bpy.ops.wm.quit_blender()
            return None
        return 1.0
    if not state["mid"] and time.time() - state["started"] > 20:
        shot("panel_running.png")
        state["mid"] = True
    if settings.status.startswith("Done") or settings.error or time.time() - state["started"] > 600:
        shot("panel_done.png")
        bpy.ops.wm.quit_blender()
        return None
    return 1.0


bpy.app.timers.register(check_tick if checks else tick, first_interval=1.0)
