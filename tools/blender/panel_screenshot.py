# The add-on's sidebar panel, for the docs: Blender with a window (under Xvfb), the add-on installed
# from its zip, a generation started from the panel; screenshots 20 s into the run and after the
# import. Driven from outside (docs/blender.md "Screenshots"): Blender's 3.4 Python cannot pick a
# sidebar tab, so the driver clicks the "matlaber" tab once this script writes OUT/ready, and writes
# OUT/clicked to start the run.
#   blender --factory-startup --python panel_screenshot.py -- MATLABER ADDON_ZIP OUT
import os
import sys
import time

import bpy

argv = sys.argv[sys.argv.index("--") + 1:]
binary, zip_path, out = argv[0], argv[1], argv[2]
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


bpy.app.timers.register(tick, first_interval=1.0)
