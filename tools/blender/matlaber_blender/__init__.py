# matlaber in Blender (docs/blender.md): a sidebar panel in the 3D view that runs the installed
# `matlaber` program in the background, "Generate object" (text to 3D) or "Paint selected mesh" (the
# appearance stage on your mesh), shows its progress and ETA from `matlaber --progress json` and
# its newest preview sheet, can
# cancel and resume a run, and imports the finished .glb with Blender's own glTF importer where the
# selected object was.
#
# Blender stays responsive: the program runs as a subprocess, two threads read its output into a
# queue, and a timer (every 0.25 s) turns the queued lines into progress, reports and, at the end,
# the import. Tests without a window manager (blender -b) call poll() themselves.

bl_info = {
    "name": "matlaber",
    "author": "matlaber contributors",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "3D View > Sidebar > matlaber",
    "description": "Text to 3D with physically meaningful materials, and painting your own meshes (MATLABER)",
    "category": "3D View",
}

import json
import os
import queue
import shlex
import shutil
import subprocess
import tempfile
import threading
import time

import bpy
from bpy.props import EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty
from mathutils import Matrix

from .metals import read_glb_json, rebuild_metals  # noqa: F401 (read_glb_json: the tests call it here)

PRESETS = [
    ("tiny", "tiny", "The project's own small model: 4 views at 128², minutes on a CPU"),
    ("cpu", "cpu", "Stable Diffusion 1.5 on a CPU: 1 view at 256², under an hour on 2 cores"),
    ("paper", "paper", "The paper's schedule: 9 views at 512², for a GPU"),
]


# ---- preferences (remembered across sessions) ------------------------------------------------
class MatlaberPreferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    binary: StringProperty(name="matlaber program", subtype="FILE_PATH", default="",
                           description="The matlaber executable; empty: 'matlaber' on the PATH")
    model: StringProperty(name="Model", subtype="FILE_PATH", default="",
                          description="Stable Diffusion weights (file or diffusers folder); empty: the project's own model")
    runs_dir: StringProperty(name="Runs folder", subtype="DIR_PATH", default="",
                             description="Where run folders are made; empty: matlaber-runs in the temporary folder")

    def draw(self, context):
        col = self.layout.column()
        col.prop(self, "binary")
        col.prop(self, "model")
        col.prop(self, "runs_dir")


def prefs(context=None):
    return (context or bpy.context).preferences.addons[__package__].preferences


# ---- per-scene settings and the run's state ---------------------------------------------------
class MatlaberSettings(bpy.types.PropertyGroup):
    prompt: StringProperty(name="Prompt", default="a gold goblet")
    negative: StringProperty(name="Negative", default="", description="Negative prompt (empty: the paper's per stage)")
    preset: EnumProperty(name="Preset", items=PRESETS, default="tiny")
    seed: IntProperty(name="Seed", default=0, min=0)
    extra: StringProperty(name="Extra options", default="",
                          description="More matlaber options, e.g. --appearance-iters 60 --res 64")
    # state (shown in the panel)
    status: StringProperty(name="Status", default="")
    progress: FloatProperty(name="Progress", default=0.0, min=0.0, max=100.0, subtype="PERCENTAGE")
    eta: StringProperty(name="ETA", default="")
    run_dir: StringProperty(name="Last run", default="")
    run_command: StringProperty(default="")     # "generate" or "paint"
    run_args: StringProperty(default="")        # the last command line (JSON list), for a resume without a run folder
    source: StringProperty(default="")          # paint: the painted object's name
    source_matrix: StringProperty(default="")   # where the result goes (16 numbers, JSON)
    error: StringProperty(name="Error", default="")
    preview: StringProperty(default="")         # the preview sheet shown in the panel: "PATH@MTIME"


# ---- the background job ------------------------------------------------------------------------
class Job:
    """One running matlaber process: its output lines are read by threads into a queue."""

    def __init__(self, args):
        self.args = args
        self.t_start = time.time()
        self.lines = queue.Queue()
        self.proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, bufsize=1)
        self.readers = [threading.Thread(target=self._read, args=(s, n), daemon=True)
                        for s, n in ((self.proc.stdout, "out"), (self.proc.stderr, "err"))]
        for t in self.readers:
            t.start()
        self.cancelled = False
        self.result = None      # the "result" event
        self.errors = []        # "error" events' messages
        self.tail = []          # the last plain lines (shown when the program fails without a message)
        self.first_eta = None   # (wall clock, seconds): the first ETA the program gave (tests compare it)
        self.t_program_end = None   # when the program said it ended (before the import, which no ETA covers)

    def _read(self, stream, name):
        for line in stream:
            self.lines.put((name, line.rstrip("\n")))

    def finished(self):
        return self.proc.poll() is not None and not any(t.is_alive() for t in self.readers) and self.lines.empty()

    def cancel(self):
        self.cancelled = True
        if self.proc.poll() is None:
            self.proc.terminate()   # checkpoints are written atomically: Resume continues from the last one


_job = None
_previews = None   # bpy.utils.previews collection: the panel's picture of the run ("run")
_preview_checked = 0.0



def job():
    return _job


def _format_eta(s):
    if s is None or s < 0:
        return "?"
    s = int(s + 0.5)
    return "%dh%02dm" % (s // 3600, s % 3600 // 60) if s >= 3600 else "%dm%02ds" % (s // 60, s % 60) if s >= 60 else "%ds" % s


def _redraw():
    """Redraws the 3D views' sidebars: the buttons' enabled state follows the job only when the
    region is drawn again (without this a greyed Generate stayed so until the mouse moved)."""
    wm = bpy.context.window_manager
    for win in (wm.windows if wm else []):
        for area in win.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()
                for region in area.regions:
                    if region.type == "UI":
                        region.tag_redraw()


def _report(level, message):
    """Into Blender's report area (the status bar and Info editor); printed in background mode."""
    try:
        bpy.ops.matlaber.report(level=level, message=message)
    except Exception:
        print("matlaber: %s: %s" % (level, message))


def _stage_text(ev):
    """'geometry 12/120, 0.9 steps/s' from a progress event (stage by name, its own step, its rate)."""
    text = "%s %d/%d" % (ev.get("stage", ev.get("label", "")), ev.get("stage_done", ev.get("done", 0)),
                         ev.get("stage_steps", ev.get("total", 0)))
    rate = ev.get("rate") or 0
    if rate > 0:
        text += ", %.2g steps/s" % rate if rate < 10 else ", %d steps/s" % rate
    return text


def _handle_line(st, j, name, line):
    if name == "err" and line.startswith("{"):
        try:
            ev = json.loads(line)
        except ValueError:
            ev = None
        if isinstance(ev, dict):
            kind = ev.get("event")
            if kind in ("begin", "plan"):
                st.status = "Loading the model"
            elif kind == "stage":
                st.status = "%s (stage %d of %d)" % (ev.get("stage", ""), int(ev.get("index", 0)) + 1, ev.get("stages", 1))
            elif kind == "progress":
                st.progress = 100.0 * min(1.0, max(0.0, float(ev.get("fraction", 0.0))))
                eta = ev.get("eta_s")
                st.eta = _format_eta(eta) if isinstance(eta, (int, float)) and eta >= 0 else ""
                if st.eta and j.first_eta is None:
                    j.first_eta = (time.time(), float(eta))
                st.status = _stage_text(ev)
            elif kind == "end":
                j.t_program_end = time.time()
                st.status = "%s: %s" % (ev.get("label", ""), ev.get("status", "done"))
            elif kind == "error":
                j.errors.append(ev.get("message", "error"))
            elif kind == "result":
                j.result = ev
            return
    if line.strip():
        j.tail = (j.tail + [line])[-8:]


def update_preview(st, settle=0.5):
    """Shows the run's newest preview sheet (RUN/previews/*.png, written every preview_every steps)
    in the panel. A file younger than `settle` seconds may still be being written: it waits."""
    global _preview_checked
    _preview_checked = time.time()
    d = os.path.join(st.run_dir, "previews") if st.run_dir else ""
    try:
        files = [os.path.join(d, f) for f in os.listdir(d) if f.endswith(".png")] if d else []
        stamped = [(os.path.getmtime(f), f) for f in files]
    except OSError:   # no folder yet, or a file removed under us
        return
    ready = [x for x in stamped if time.time() - x[0] >= settle]
    if not ready:
        return
    mtime, newest = max(ready)
    key = "%s@%.3f" % (newest, mtime)
    if key == st.preview:
        return
    if _previews is not None:
        _previews.clear()   # load() refuses a key it holds; force_reload: the same path may hold a new sheet
        _previews.load("run", newest, "IMAGE", force_reload=True)
    st.preview = key


def preview_path(st):
    """The file shown in the panel, or ''."""
    return st.preview.rsplit("@", 1)[0] if st.preview else ""


def poll(context=None):
    """Processes the job's output; at the end imports the result or reports the error. Returns True
    while the job runs (the timer's and the tests' loop condition)."""
    global _job
    j = _job
    if j is None:
        return False
    st = (context or bpy.context).scene.matlaber
    try:
        while True:
            name, line = j.lines.get_nowait()
            _handle_line(st, j, name, line)
    except queue.Empty:
        pass
    if not j.finished():
        if time.time() - _preview_checked >= 1.0:
            update_preview(st)
        _redraw()
        return True
    _job = None
    update_preview(st, settle=0.0)   # the process has ended: every file is whole
    rc = j.proc.returncode
    if j.cancelled:
        st.status = "Cancelled: Resume continues from the last checkpoint"
        st.eta = ""
        _report("WARNING", "matlaber: run cancelled (%s); Resume continues it" % st.run_dir)
    elif rc == 0 and j.result and j.result.get("finished"):
        st.progress = 100.0
        st.eta = ""
        try:
            obj = import_result(st, j.result.get("glb", os.path.join(st.run_dir, "final", "asset.glb")))
            st.status = "Done: %s" % obj.name
            _report("INFO", "matlaber: imported %s (%d vertices, %d faces)" % (obj.name, len(obj.data.vertices),
                                                                               len(obj.data.polygons)))
        except Exception as e:   # the importer's own failure
            st.error = "import failed: %s" % e
            st.status = "Import failed"
            _report("ERROR", "matlaber: " + st.error)
    elif rc == 0:
        st.status = "Stopped: Resume continues it"
    else:
        msg = j.errors[-1] if j.errors else (j.tail[-1] if j.tail else "exit status %d" % rc)
        st.error = msg
        st.status = "Failed"
        st.eta = ""
        _discard_unstarted(st)
        _report("ERROR", "matlaber: " + msg)
    _redraw()
    return False


def _discard_unstarted(st):
    """A run that failed before the program made its folder leaves nothing behind (the add-on's own
    folder and the painted mesh's copy go) and offers no Resume: there is nothing to continue."""
    if not st.run_dir or os.path.exists(st.run_dir):
        return
    folder = os.path.dirname(st.run_dir)
    try:
        if os.path.isfile(os.path.join(folder, "input.obj")):
            os.remove(os.path.join(folder, "input.obj"))
        os.rmdir(folder)
    except OSError:   # something else was put there: left as it is
        pass
    st.run_dir = ""


def _redraw_once():
    _redraw()
    return None


def _timer():
    try:
        if poll():
            return 0.25
        bpy.app.timers.register(_redraw_once, first_interval=0.3)   # once more, after the reports
        return None
    except Exception as e:   # never let the timer die silently
        print("matlaber: poll failed: %s" % e)
        return None


def start(context, args, command, run_dir):
    """Starts matlaber with args; the timer follows it."""
    global _job
    st = context.scene.matlaber
    st.status, st.error, st.eta, st.progress = "Starting", "", "", 0.0
    st.run_dir, st.run_command, st.run_args = run_dir, command, json.dumps(args)
    if not st.preview.startswith(os.path.join(run_dir, "")):   # a resume keeps its run's picture
        st.preview = ""
    _job = Job(args)
    if not bpy.app.background:
        bpy.app.timers.register(_timer, first_interval=0.25)


def binary(context):
    b = prefs(context).binary
    b = bpy.path.abspath(b) if b else (shutil.which("matlaber") or "")
    if not b or not os.path.isfile(b):
        raise RuntimeError("the matlaber program was not found: set it in the add-on's preferences "
                           "(Edit > Preferences > Add-ons > matlaber)")
    return b


def new_run_dir(context, name):
    base = prefs(context).runs_dir
    base = bpy.path.abspath(base) if base else os.path.join(tempfile.gettempdir(), "matlaber-runs")
    safe = "".join(c if c.isalnum() or c in "-_" else "_" for c in name)[:40] or "run"
    d = os.path.join(base, "%s_%s" % (safe, time.strftime("%Y%m%d-%H%M%S")))
    n = 1
    while os.path.exists(d):
        n += 1
        d = os.path.join(base, "%s_%s_%d" % (safe, time.strftime("%Y%m%d-%H%M%S"), n))
    os.makedirs(d)
    return d


# Options the add-on gives the program itself, and where a person sets them instead
OWN_OPTIONS = {
    "-p": "the Prompt field", "--prompt": "the Prompt field", "-n": "the Negative field",
    "--negative": "the Negative field", "--preset": "the Preset field", "--seed": "the Seed field",
    "-m": "the Model field", "--model": "the Model field", "-o": "the add-on (a new run folder each time)",
    "--out": "the add-on (a new run folder each time)", "--mesh": "the add-on (the selected object)",
    "--progress": "the add-on", "--resume": "the Resume button", "--prompts": "the add-on (one prompt per run)",
    "--asset": "the add-on (it imports the run's asset)",
}


def extra_options(text):
    """The Extra options as arguments; ValueError naming the first one the add-on sets itself."""
    try:
        words = shlex.split(text)
    except ValueError as e:
        raise ValueError("Extra options: %s" % e)
    for w in words:
        key = w.split("=", 1)[0]
        if key in OWN_OPTIONS:
            raise ValueError("Extra options: %s is set by %s; remove it" % (key, OWN_OPTIONS[key]))
    return words


def check_prompt(st):
    """Before anything is started or made: the program would refuse an empty prompt anyway."""
    if not st.prompt.strip():
        raise ValueError("A prompt is required: type what to make into Prompt")


def common_args(context, command):
    st = context.scene.matlaber
    check_prompt(st)
    extra = extra_options(st.extra)
    a = [binary(context), "--progress", "json", command, "-p", st.prompt, "--preset", st.preset, "--seed", str(st.seed)]
    if st.negative:
        a += ["-n", st.negative]
    model = prefs(context).model
    if model:
        a += ["-m", bpy.path.abspath(model)]
    return a + extra


def refuse(op, st, message):
    """A run that cannot start: said in the panel and the report area; no folder, no Resume."""
    st.status, st.error, st.eta, st.progress, st.run_dir = "Not started", message, "", 0.0, ""
    op.report({"ERROR"}, message)
    _redraw()
    return {"CANCELLED"}


def _matrix_text(m):
    return json.dumps([v for row in m for v in row])


def import_result(st, glb):
    """The .glb through Blender's glTF importer (vertices merged back where only UVs split them),
    placed where the source object was (paint) or at the 3D cursor (generate)."""
    try:
        import numpy
    except ImportError:
        raise RuntimeError("Blender's glTF importer needs numpy (Debian: apt-get install python3-numpy)")
    if "bool" not in vars(numpy):   # (hasattr itself raises NumPy 1.24's FutureWarning about np.bool)
        # Blender 3.4's importer (Debian 12's Blender) still uses np.bool, which NumPy 1.24 removed:
        # the alias it stood for, so that the import runs
        numpy.bool = bool
    before = set(bpy.data.objects)
    bpy.ops.import_scene.gltf(filepath=glb, merge_vertices=True)
    new = [o for o in bpy.data.objects if o not in before]
    meshes = [o for o in new if o.type == "MESH"]
    if not meshes:
        raise RuntimeError("%s holds no mesh" % glb)
    vals = json.loads(st.source_matrix) if st.source_matrix else None
    place = Matrix([vals[0:4], vals[4:8], vals[8:12], vals[12:16]]) if vals else Matrix.Identity(4)
    for o in new:
        if o.parent is None:
            o.matrix_world = place @ o.matrix_world
    obj = meshes[0]
    obj.name = (st.source + "_painted") if st.run_command == "paint" and st.source else "matlaber_" + st.prompt[:30]
    mats = {s.material for o in meshes for s in o.material_slots if s.material is not None}
    try:
        notes = rebuild_metals(glb, mats)
    except Exception as e:   # a malformed file or an importer we do not know: the import itself stands
        notes = [("", "metals not rebuilt: %s" % e)]
    for name, note in notes:   # (the material is often named "matlaber" too: named last, in quotes)
        _report("WARNING" if "not rebuilt" in note else "INFO",
                "matlaber: %s%s" % (note, " (material '%s')" % name if name else ""))
    return obj


# ---- operators -----------------------------------------------------------------------------------
class MATLABER_OT_report(bpy.types.Operator):
    """Puts a message of the program into Blender's report area"""
    bl_idname = "matlaber.report"
    bl_label = "matlaber report"
    bl_options = {"INTERNAL"}
    level: StringProperty(default="INFO")
    message: StringProperty(default="")

    def execute(self, context):
        self.report({self.level}, self.message)
        return {"FINISHED"}


class _Idle:
    @classmethod
    def poll(cls, context):
        return _job is None


class MATLABER_OT_generate(_Idle, bpy.types.Operator):
    """Text to 3D: runs matlaber generate in the background and imports the result at the 3D cursor"""
    bl_idname = "matlaber.generate"
    bl_label = "Generate object"

    @classmethod
    def poll(cls, context):
        if _job is not None:
            cls.poll_message_set("A run is in progress: wait for it or cancel it")
            return False
        return True

    def execute(self, context):
        st = context.scene.matlaber
        try:
            args = common_args(context, "generate")
            run = os.path.join(new_run_dir(context, st.prompt), "run")
            args += ["-o", run]
        except Exception as e:
            return refuse(self, st, str(e))
        st.source = ""
        st.source_matrix = _matrix_text(Matrix.Translation(context.scene.cursor.location))
        start(context, args, "generate", run)
        return {"FINISHED"}


class MATLABER_OT_busy(bpy.types.Operator):
    """A run is in progress"""
    bl_idname = "matlaber.busy"
    bl_label = "A run is in progress"
    bl_options = {"INTERNAL"}

    @classmethod
    def poll(cls, context):
        cls.poll_message_set("A run is in progress: wait for it or cancel it")
        return False

    def execute(self, context):
        return {"CANCELLED"}


class MATLABER_OT_paint(_Idle, bpy.types.Operator):
    """Paints the selected mesh: exports it as OBJ, runs matlaber paint in the background, imports the
    textured result where the mesh is"""
    bl_idname = "matlaber.paint_selected"
    bl_label = "Paint selected mesh"

    @classmethod
    def poll(cls, context):
        if _job is not None:
            cls.poll_message_set("A run is in progress: wait for it or cancel it")
            return False
        o = context.active_object
        if o is None or o.type != "MESH":
            cls.poll_message_set("Select a mesh object to paint (click it in the 3D view)")
            return False
        return True

    @classmethod
    def description(cls, context, properties):
        o = context.active_object
        if o is None or o.type != "MESH":
            return "Select a mesh object first: this paints the selected mesh"
        return "Paints %s: runs matlaber paint in the background and imports the textured result where it is" % o.name

    def execute(self, context):
        st = context.scene.matlaber
        obj = context.active_object
        folder = None
        try:
            args = common_args(context, "paint")
            folder = new_run_dir(context, obj.name)
            mesh_path = os.path.join(folder, "input.obj")
            export_local_obj(context, obj, mesh_path)
            run = os.path.join(folder, "run")
            args += ["--mesh", mesh_path, "-o", run]
        except Exception as e:
            if folder:   # nothing of a run that never started is kept
                shutil.rmtree(folder, ignore_errors=True)
            return refuse(self, st, str(e))
        st.source = obj.name
        st.source_matrix = _matrix_text(obj.matrix_world)
        start(context, args, "paint", run)
        return {"FINISHED"}


def export_local_obj(context, obj, path):
    """obj alone, in its own coordinates (the result is placed by its matrix), with its UVs and
    without normals (matlaber welds smooth normals, which lets the importer merge seam vertices
    again), modifiers applied, +y up as matlaber's frame."""
    selected = list(context.selected_objects)
    active = context.view_layer.objects.active
    saved = obj.matrix_world.copy()
    try:
        for o in selected:
            o.select_set(False)
        obj.select_set(True)
        context.view_layer.objects.active = obj
        obj.matrix_world = Matrix.Identity(4)
        context.view_layer.update()
        bpy.ops.wm.obj_export(filepath=path, export_selected_objects=True, export_uv=True, export_normals=False,
                              export_materials=False, apply_modifiers=True, forward_axis="NEGATIVE_Z", up_axis="Y")
    finally:
        obj.matrix_world = saved
        obj.select_set(False)
        for o in selected:
            o.select_set(True)
        context.view_layer.objects.active = active
        context.view_layer.update()
    if not os.path.isfile(path):
        raise RuntimeError("Blender's OBJ export wrote nothing to %s" % path)


class MATLABER_OT_cancel(bpy.types.Operator):
    """Stops the running matlaber (Resume continues it from its last checkpoint)"""
    bl_idname = "matlaber.cancel"
    bl_label = "Cancel"

    @classmethod
    def poll(cls, context):
        return _job is not None

    def execute(self, context):
        _job.cancel()
        return {"FINISHED"}


class MATLABER_OT_resume(_Idle, bpy.types.Operator):
    """Continues the last run where it stopped (or starts it again when it stopped before its run folder existed)"""
    bl_idname = "matlaber.resume"
    bl_label = "Resume"

    @classmethod
    def poll(cls, context):
        st = context.scene.matlaber
        if _job is not None or not st.run_dir or st.status.startswith("Done"):
            cls.poll_message_set("Nothing to resume: no run was stopped")
            return False
        return True

    def execute(self, context):
        st = context.scene.matlaber
        if os.path.isfile(os.path.join(st.run_dir, "config.json")):
            try:
                args = [binary(context), "--progress", "json", st.run_command, "--resume", st.run_dir]
            except Exception as e:
                self.report({"ERROR"}, str(e))
                return {"CANCELLED"}
        else:
            args = json.loads(st.run_args)
        start(context, args, st.run_command, st.run_dir)
        return {"FINISHED"}


# ---- the panel -------------------------------------------------------------------------------------
def _wrap(text, width_px, scale):
    """Words into lines no wider than width_px in the interface's font (blf measures them)."""
    try:
        import blf
        style = bpy.context.preferences.ui_styles[0].widget_label
        blf.size(0, style.points * scale)   # (3.4's dpi argument defaults to 72: points as pixels)

        def width(t):
            return blf.dimensions(0, t)[0]
    except Exception:   # no font: about 7 pixels a character
        def width(t):
            return 7.0 * scale * len(t)
    lines = []
    for word in text.split():
        if lines and width(lines[-1] + " " + word) <= width_px:
            lines[-1] += " " + word
        else:
            lines.append(word)
    return lines or [""]


def wrapped_label(layout, context, text, icon="NONE"):
    """text over as many lines as the sidebar's width needs: one label is cut short in the middle
    ("A prompt is...into Prompt")."""
    scale = context.preferences.system.ui_scale
    # the sidebar's margins and the box's (about 60 pixels), and the icon's column (40 more)
    width_px = (context.region.width if context.region else 300) - (60 if icon == "NONE" else 100) * scale
    col = layout.column(align=True)
    for i, line in enumerate(_wrap(text, max(width_px, 80 * scale), scale)):
        col.label(text=line, icon=icon if i == 0 else ("BLANK1" if icon != "NONE" else "NONE"))


class MATLABER_PT_panel(bpy.types.Panel):
    bl_label = "matlaber"
    bl_idname = "MATLABER_PT_panel"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "matlaber"

    def draw(self, context):
        st = context.scene.matlaber
        p = prefs(context)
        col = self.layout.column()
        # labels above their fields: beside them the sidebar cut them to "Nega..." and "Extra..."
        for owner, key, label in ((st, "prompt", "Prompt"), (st, "negative", "Negative prompt"), (p, "model", "Model")):
            col.label(text=label)
            col.prop(owner, key, text="")
        row = col.row()
        row.prop(st, "preset", text="")
        row.prop(st, "seed")
        col.label(text="Extra options")
        col.prop(st, "extra", text="")
        col.separator()
        # While a run goes, greyed stand-ins of another operator: Blender keeps the button under the
        # mouse as it was (greyed) through redraws until the mouse leaves it, so the same Generate
        # button, clicked and left under a still mouse, stayed greyed and refused clicks after the
        # run ended. A button of another operator is not carried over: the new Generate is drawn anew.
        for op, icon in ((MATLABER_OT_generate, "MESH_MONKEY"), (MATLABER_OT_paint, "BRUSH_DATA")):
            col.operator(op.bl_idname if _job is None else MATLABER_OT_busy.bl_idname, text=op.bl_label, icon=icon)
        if _job is not None or st.status:
            box = col.box()
            wrapped_label(box, context, st.status or "Running")
            row = box.row()
            row.enabled = False
            row.prop(st, "progress", text="ETA " + st.eta if st.eta else "Progress", slider=True)
            row = box.row()
            row.operator(MATLABER_OT_cancel.bl_idname, icon="CANCEL")
            row.operator(MATLABER_OT_resume.bl_idname, icon="PLAY")
            if st.error:
                wrapped_label(box, context, st.error, icon="ERROR")
            if st.preview and _previews is not None and "run" in _previews:
                box.template_icon(icon_value=_previews["run"].icon_id, scale=9.0)
                stage, _, step = os.path.splitext(os.path.basename(preview_path(st)))[0].partition("_")
                box.label(text="%s, step %s" % (stage, step.lstrip("0") or "0"))


CLASSES = (MatlaberPreferences, MatlaberSettings, MATLABER_OT_report, MATLABER_OT_generate, MATLABER_OT_busy,
           MATLABER_OT_paint,
           MATLABER_OT_cancel, MATLABER_OT_resume, MATLABER_PT_panel)


def register():
    global _previews
    import bpy.utils.previews
    _previews = bpy.utils.previews.new()
    for c in CLASSES:
        bpy.utils.register_class(c)
    bpy.types.Scene.matlaber = PointerProperty(type=MatlaberSettings)


def unregister():
    if _job is not None:
        _job.cancel()
    if bpy.app.timers.is_registered(_timer):
        bpy.app.timers.unregister(_timer)
    del bpy.types.Scene.matlaber
    for c in reversed(CLASSES):
        bpy.utils.unregister_class(c)
    global _previews
    if _previews is not None:
        bpy.utils.previews.remove(_previews)
        _previews = None
