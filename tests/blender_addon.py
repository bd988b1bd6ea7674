# The Blender add-on (tools/blender, docs/blender.md) in Blender's background mode, run by
# tests/cli_blender.sh:  blender -b --factory-startup --python tests/blender_addon.py -- MATLABER ZIP
# Installs the add-on from its zip; refuses an empty prompt (said in the panel, no run folder, no
# Resume), Paint without a selected mesh (the poll message says why) and Extra options the add-on
# sets itself; paints an ico sphere (UVs, placed away from the origin, rotated and scaled) with the
# project's own model at tiny settings, checks the imported object (vertex and face counts, UVs,
# placement, a material whose base colour, roughness and specular come from image textures), then
# cancels a run and resumes it; the first ETA of a run within a factor of 2 of its duration (the
# time until the ETA showed plus the ETA, against the time the run took). Exit status 0 when every
# check passes.
import os
import re
import sys
import time
import warnings

import bpy

argv = sys.argv[sys.argv.index("--") + 1:]
MATLABER, ZIP = argv[0], argv[1]
failures = []


def check(ok, what):
    print(("ok   " if ok else "FAIL ") + what, flush=True)
    if not ok:
        failures.append(what)


def wait(addon, timeout, until=None):
    """Drives the add-on's poll (no timers in background mode) until the job ends or until(job)."""
    t0 = time.time()
    while addon.poll():
        if until and addon.job() and until(addon.job()):
            return True
        if time.time() - t0 > timeout:
            return False
        time.sleep(0.1)
    return True


def upstream_image(socket, depth=0):
    """The image texture node feeding socket through any chain of nodes, or None."""
    for link in socket.links:
        n = link.from_node
        if n.type == "TEX_IMAGE" and n.image is not None:
            return n
        for s in n.inputs:
            if depth < 6 and s.is_linked:
                found = upstream_image(s, depth + 1)
                if found:
                    return found
    return None


def corners(obj):
    """Sorted (world position, uv) of every face corner, rounded."""
    m = obj.data
    uv = m.uv_layers.active.data
    W = obj.matrix_world
    out = []
    for loop in m.loops:
        p = W @ m.vertices[loop.vertex_index].co
        out.append((round(p.x, 3), round(p.y, 3), round(p.z, 3), round(uv[loop.index].uv.x, 3), round(uv[loop.index].uv.y, 3)))
    return sorted(out)


# ---- install from the zip, as a user would -------------------------------------------------------
bpy.ops.preferences.addon_install(filepath=ZIP, overwrite=True)
bpy.ops.preferences.addon_enable(module="matlaber_blender")
import matlaber_blender as addon  # noqa: E402

check("matlaber_blender" in bpy.context.preferences.addons, "add-on installed from the zip and enabled")
p = bpy.context.preferences.addons["matlaber_blender"].preferences
p.binary = MATLABER
p.runs_dir = os.path.join(os.path.dirname(ZIP), "runs")
check(hasattr(bpy.types, "MATLABER_PT_panel"), "sidebar panel registered")

# ---- a mesh to paint ---------------------------------------------------------------------------------
for o in list(bpy.data.objects):
    bpy.data.objects.remove(o)
bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=2, radius=1.0, location=(3.0, -2.0, 1.5), rotation=(0.3, 0.2, 0.9))
src = bpy.context.active_object
src.scale = (2.0, 2.0, 0.5)
bpy.context.view_layer.update()
n_verts, n_faces = len(src.data.vertices), len(src.data.polygons)
check(len(src.data.uv_layers) > 0, "the ico sphere has UVs (%d vertices, %d faces)" % (n_verts, n_faces))
src_corners = corners(src)

st = bpy.context.scene.matlaber
st.preset = "tiny"
st.seed = 1


def run_folders():
    return sorted(os.listdir(p.runs_dir)) if os.path.isdir(p.runs_dir) else []


def refused(op):
    """Calls an operator that should refuse: True when it was cancelled (an ERROR report reaches
    Python as a RuntimeError)."""
    try:
        return op() == {"CANCELLED"}
    except RuntimeError:
        return True


def first_eta(j, t_end):
    """The run's duration as its first ETA foretold it (the time until that ETA plus the ETA) and as
    it was, and the ETA against the time left then: None when it showed no ETA."""
    if j is None or j.first_eta is None:
        return None
    t, eta = j.first_eta
    t_end = j.t_program_end or t_end   # the program's own end: the ETA does not cover Blender's import
    return {"foretold": t - j.t_start + eta, "real": t_end - j.t_start, "eta": eta, "left": t_end - t}


# Under the sanitizers the program's stages slow down by different factors (the export's memory work
# most), so the ETA's cost model, which is the optimised build's, is not checked there.
SANITIZED = os.environ.get("MLB_TEST_SANITIZED") == "1"


def eta_sound(e):
    return SANITIZED or 0.5 <= e["foretold"] / e["real"] <= 2


def eta_text(e):
    return "none" if e is None else "%.1f s foretold, %.1f s real; ETA %.1f s with %.1f s left%s" % (
        e["foretold"], e["real"], e["eta"], e["left"], "; the ratio is not checked under the sanitizers" if SANITIZED else "")


# ---- refused before anything starts: an empty prompt, no mesh selected, the add-on's own options ------
before = run_folders()
for prompt in ("", "   "):
    st.prompt = prompt
    check(refused(bpy.ops.matlaber.generate), "Generate with the prompt %r refused" % prompt)
    check("prompt is required" in st.error and st.status == "Not started",
          "the panel says a prompt is required (%s: %s)" % (st.status, st.error))
    check(addon.job() is None, "no program started")
    check(run_folders() == before, "no run folder made (%s)" % run_folders())
    check(not bpy.ops.matlaber.resume.poll(), "no Resume after a refused start")
check(refused(bpy.ops.matlaber.paint_selected) and "prompt is required" in st.error and run_folders() == before,
      "Paint with an empty prompt refused, no run folder (%s)" % st.error)
st.prompt = "a red vase"
st.extra = "--appearance-iters 3 --mesh /tmp/other.obj"
check(refused(bpy.ops.matlaber.paint_selected) and "--mesh is set by the add-on" in st.error,
      "--mesh in Extra options refused (%s)" % st.error)
st.extra = "-o /tmp/elsewhere"
check(refused(bpy.ops.matlaber.generate) and "-o is set by the add-on" in st.error,
      "-o in Extra options refused (%s)" % st.error)
check(run_folders() == before, "no run folder made for refused options")
bpy.ops.object.select_all(action="DESELECT")
bpy.context.view_layer.objects.active = None
check(not bpy.ops.matlaber.paint_selected.poll(), "Paint is off with nothing selected")
try:
    bpy.ops.matlaber.paint_selected()
    why = ""
except RuntimeError as e:   # Blender puts the operator's poll message into the error
    why = str(e)
check("Select a mesh object" in why, "the disabled Paint says why (%s)" % why)
bpy.context.view_layer.objects.active = src
src.select_set(True)

# the add-on's own code raises no warning (NumPy 1.24 warned on its np.bool probe)
addon_warnings = []
_show = warnings.showwarning


def _record(message, category, filename, lineno, file=None, line=None):
    if "matlaber_blender" in filename:
        addon_warnings.append("%s: %s" % (category.__name__, message))
    _show(message, category, filename, lineno, file, line)


warnings.showwarning = _record
warnings.simplefilter("always")
st.extra = "--appearance-iters 3 --res 32 --views 1 --export-texture 64 --preview-every 0 --checkpoint-every 1"

# ---- paint, wait, check the imported object -----------------------------------------------------------
t0 = time.time()
check(bpy.ops.matlaber.paint_selected() == {"FINISHED"}, "Paint selected mesh started")
j = addon.job()
check(wait(addon, 300), "paint finished within 300 s (%.1f s)" % (time.time() - t0))
e = first_eta(j, time.time())
check(e is None or eta_sound(e), "the first ETA, if any, within 2x of the run's duration (%s)" % eta_text(e))
check(not addon_warnings, "no warnings from the add-on (%s)" % addon_warnings)
print("status:", st.status, "| error:", st.error, flush=True)
check(st.status.startswith("Done"), "status says done")
check(st.progress == 100.0, "progress at 100%")
out = bpy.data.objects.get(src.name + "_painted")
check(out is not None, "imported object %s_painted" % src.name)
if out is not None:
    check(len(out.data.vertices) == n_verts, "vertex count kept (%d, input %d)" % (len(out.data.vertices), n_verts))
    check(len(out.data.polygons) == n_faces, "face count kept (%d, input %d)" % (len(out.data.polygons), n_faces))
    check(len(out.data.uv_layers) > 0, "imported object has UVs")
    if len(out.data.uv_layers):
        c = corners(out)
        diff = max((max(abs(a - b) for a, b in zip(x, y)) for x, y in zip(c, src_corners)), default=1.0)
        check(len(c) == len(src_corners) and diff <= 2e-3,
              "world positions and UVs of every corner as the input's (largest difference %.2g)" % diff)
    d = max(abs(a - b) for ra, rb in zip(out.matrix_world, src.matrix_world) for a, b in zip(ra, rb))
    check(d < 1e-5, "placed where the source object is (matrix difference %.2g)" % d)
    mats = [m for m in out.data.materials if m is not None]
    check(len(mats) == 1 and mats[0].use_nodes, "one node material")
    if mats:
        bsdf = next((n for n in mats[0].node_tree.nodes if n.type == "BSDF_PRINCIPLED"), None)
        check(bsdf is not None, "Principled BSDF")
        if bsdf is not None:
            for name in ("Base Color", "Roughness", "Specular"):
                img = upstream_image(bsdf.inputs[name])
                check(img is not None, "%s from an image texture%s" % (name, " (%s)" % img.image.name if img else ""))

# ---- cancel, then resume ----------------------------------------------------------------------------------
bpy.ops.object.select_all(action="DESELECT")
src.select_set(True)
bpy.context.view_layer.objects.active = src
st.extra = "--appearance-iters 40 --res 32 --views 1 --export-texture 64 --preview-every 5 --checkpoint-every 1"
check(bpy.ops.matlaber.paint_selected() == {"FINISHED"}, "second paint started")
def appearance_steps():
    m = re.match(r"appearance (\d+)/", st.status)
    return int(m.group(1)) if m else 0


reached = wait(addon, 300, until=lambda j: st.eta != "" and appearance_steps() >= 2)   # checkpoints every step
check(reached and addon.job() is not None, "running at %.0f%% (%s, ETA %s)" % (st.progress, st.status, st.eta))
check(st.eta not in ("", "?"), "an ETA is shown (%s)" % st.eta)
check(bpy.ops.matlaber.cancel() == {"FINISHED"}, "Cancel")
check(wait(addon, 60), "the process ended after Cancel")
check(st.status.startswith("Cancelled"), "status says cancelled (%s)" % st.status)
run = st.run_dir
check(os.path.isfile(os.path.join(run, "checkpoints", "appearance.safetensors")), "the cancelled run left a checkpoint")
check(not os.path.exists(os.path.join(run, "final", "asset.glb")), "no asset after Cancel")
before = len(bpy.data.objects)
check(bpy.ops.matlaber.resume() == {"FINISHED"}, "Resume")
j = addon.job()
check(wait(addon, 300), "the resumed run finished")
e = first_eta(j, time.time())
check(e is not None and eta_sound(e), "the resumed run showed an ETA, its first within 2x of the run's duration (%s)"
      % eta_text(e))
check(st.status.startswith("Done"), "resumed run done (%s %s)" % (st.status, st.error))
check(len(bpy.data.objects) == before + 1, "the resumed run's result imported")
# the panel shows the run's newest preview sheet (every 5 steps: the last one at step 40)
shown = addon.preview_path(st)
check(os.path.basename(shown) == "appearance_000040.png" and os.path.dirname(shown) == os.path.join(run, "previews"),
      "the panel shows the newest preview (%s)" % shown)
check("run" in addon._previews, "the preview loaded into the panel's preview collection")
with open(os.path.join(run, "loss.csv")) as f:
    rows = [line for line in f if line[:1].isdigit()]
check(len(rows) == 40, "loss.csv has the 40 steps once each (%d rows)" % len(rows))

# ---- an error from the program reaches the report -----------------------------------------------------------
folders_before_failure = run_folders()
bad = bpy.data.objects.new("empty_mesh", bpy.data.meshes.new("empty_mesh"))
bpy.context.scene.collection.objects.link(bad)
bpy.ops.object.select_all(action="DESELECT")
bad.select_set(True)
bpy.context.view_layer.objects.active = bad
bpy.ops.matlaber.paint_selected()
check(wait(addon, 120), "the failing run ended")
check(st.status == "Failed" and "no faces" in st.error, "the program's error shown (%s)" % st.error)
check(not bpy.ops.matlaber.resume.poll(), "a run that failed before its folder existed offers no Resume")
check(run_folders() == folders_before_failure, "nothing left of the failed start (%s)" % run_folders())

print("%d failed" % len(failures), flush=True)
sys.exit(1 if failures else 0)
