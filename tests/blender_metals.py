# The add-on's metal rebuild (tools/blender, docs/blender.md "Metals") in Blender's background mode,
# run by tests/cli_blender.sh:
#   blender -b --factory-startup --python tests/blender_metals.py -- MATLABER ZIP GOLD.glb RED.glb [SPHERE.glb|-]
# GOLD / RED: `matlaber catalogue export --material gold|red` (the catalogue's BRDF in every texel);
# SPHERE: test_export's sphere (ks dielectric on the left half of the texture, gold on the right).
# What a material feeds the Principled BSDF is measured by Cycles itself: the socket's source wired
# to an Emission shader and baked into a float image over the mesh's UVs. Exit status 0 when every
# check passes.
import json
import os
import subprocess
import sys

import bpy
import numpy as np

argv = sys.argv[sys.argv.index("--") + 1:]
MATLABER, ZIP, GOLD, RED = argv[:4]
SPHERE = argv[4] if len(argv) > 4 and argv[4] != "-" else None
failures = []


def check(ok, what):
    print(("ok   " if ok else "FAIL ") + what, flush=True)
    if not ok:
        failures.append(what)


def fmt(v):
    return "(" + ", ".join("%.3f" % x for x in v) + ")"


def principled(mat):
    return next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")


def import_raw(glb):
    """Blender's glTF importer alone (what the add-on did before the rebuild)."""
    before = set(bpy.data.objects)
    bpy.ops.import_scene.gltf(filepath=glb, merge_vertices=True)
    return next(o for o in bpy.data.objects if o not in before and o.type == "MESH")


def import_addon(glb):
    """Through the add-on's import of a finished run (the importer, then the rebuild)."""
    st = bpy.context.scene.matlaber
    st.run_command, st.prompt, st.source, st.source_matrix = "generate", os.path.basename(glb), "", ""
    return addon.import_result(st, glb)


def bake(obj, socket, size=32):
    """[size, size, 3] linear values that obj's material feeds its Principled BSDF's socket, baked
    by Cycles over obj's UVs; texels no face covers are NaN."""
    mat = obj.material_slots[0].material.copy()
    nt = mat.node_tree
    inp = principled(mat).inputs[socket]
    em = nt.nodes.new("ShaderNodeEmission")
    if inp.is_linked:
        nt.links.new(inp.links[0].from_socket, em.inputs["Color"])
    else:
        v = inp.default_value
        em.inputs["Color"].default_value = tuple(v) if hasattr(v, "__len__") else (v, v, v, 1.0)
    out = next(n for n in nt.nodes if n.type == "OUTPUT_MATERIAL" and n.is_active_output)
    nt.links.new(em.outputs[0], out.inputs["Surface"])
    img = bpy.data.images.new("bake", size, size, float_buffer=True)
    img.pixels.foreach_set(np.tile(np.float32([-1, -1, -1, 1]), size * size))   # marks texels the bake leaves
    tex = nt.nodes.new("ShaderNodeTexImage")
    tex.image = img
    nt.nodes.active = tex
    tmp = bpy.data.objects.new("bake_tmp", obj.data.copy())
    tmp.data.materials.clear()
    tmp.data.materials.append(mat)
    bpy.context.scene.collection.objects.link(tmp)
    bpy.ops.object.select_all(action="DESELECT")
    tmp.select_set(True)
    bpy.context.view_layer.objects.active = tmp
    bpy.ops.object.bake(type="EMIT", margin=0, use_clear=False)
    px = np.empty(size * size * 4, np.float32)
    img.pixels.foreach_get(px)
    px = px.reshape(size, size, 4)
    rgb = np.where(px[..., :1] >= 0, px[..., :3], np.nan)
    data = tmp.data
    bpy.data.objects.remove(tmp)
    bpy.data.meshes.remove(data)
    bpy.data.materials.remove(mat)
    bpy.data.images.remove(img)
    return rgb


def graph(mat):
    """A material's node graph as comparable data: nodes, links, the BSDF's unlinked values."""
    nt = mat.node_tree
    # image names without the .001 Blender adds when the same file is imported twice
    nodes = sorted((n.type, n.label, n.image.name.split(".")[0] if n.type == "TEX_IMAGE" and n.image else "")
                   for n in nt.nodes)
    links = sorted((l.from_node.type, l.from_node.label, l.from_socket.identifier, l.to_node.type, l.to_socket.identifier)
                   for l in nt.links)
    values = [(i.name, round(float(i.default_value), 6)) for i in principled(mat).inputs
              if i.type == "VALUE" and not i.is_linked]
    return nodes, links, values


def expected(kd, ks):
    """The mapping the add-on documents, for one BRDF: (Base Color, Metallic, Specular)."""
    d = min(ks.min(), 0.08)
    m = np.clip((ks.max() - d) / ((kd + ks).max() - d), 0, 1)
    return np.minimum(kd + ks - (1 - m) * d, 1.0), m, d / 0.08


# ---- the add-on, installed from its zip as a user would ------------------------------------------
bpy.ops.preferences.addon_install(filepath=ZIP, overwrite=True)
bpy.ops.preferences.addon_enable(module="matlaber_blender")
import matlaber_blender as addon  # noqa: E402

if not hasattr(np, "bool"):
    np.bool = bool   # Blender 3.4's importer on NumPy >= 1.24, as the add-on does
for o in list(bpy.data.objects):
    bpy.data.objects.remove(o)
scene = bpy.context.scene
scene.render.engine = "CYCLES"
scene.cycles.device = "CPU"
scene.cycles.samples = 1
scene.cycles.use_denoising = False   # Debian's Blender has no OpenImageDenoise: with it on, bakes come out black
cat = json.loads(subprocess.run([MATLABER, "catalogue", "list", "--json"], check=True, capture_output=True, text=True).stdout)
brdf = {m["name"]: np.array(m["brdf"], np.float64) for m in cat["materials"]}
check("gold" in brdf and "red" in brdf, "the catalogue's BRDFs from matlaber (%d materials)" % len(brdf))

# ---- a gold goblet: kd ~ 0, ks = gold's F0 ---------------------------------------------------------
kd, ks = brdf["gold"][:3], brdf["gold"][3:6]
raw = import_raw(GOLD)
raw_base = np.nanmean(bake(raw, "Base Color").reshape(-1, 3), axis=0)
check(raw_base.max() < 0.05, "the problem: the importer's gold has the dark kd as base colour %s (kd %s)" % (fmt(raw_base), fmt(kd)))
gold = import_addon(GOLD)
mat = gold.material_slots[0].material
check(mat.get("matlaber_metals") == "rebuilt", "gold material rebuilt (%s)" % mat.get("matlaber_metals"))
base = bake(gold, "Base Color").reshape(-1, 3)
metal = bake(gold, "Metallic")[..., 0].ravel()
spec = bake(gold, "Specular")[..., 0].ravel()
covered = ~np.isnan(metal)
check(covered.sum() > 100, "the bake covers %d of 1024 texels" % covered.sum())
b, m, s = np.nanmean(base, axis=0), np.nanmin(metal), np.nanmean(spec)
eb, em, es = expected(kd, ks)
check(b[0] > b[1] > b[2] and b[0] > 0.9, "gold base colour %s: R > G > B, bright (ks %s)" % (fmt(b), fmt(ks)))
check(np.abs(b - eb).max() < 0.01 and np.nanmax(np.abs(base - eb)) < 0.02,
      "base colour as the mapping gives %s (largest texel difference %.4f)" % (fmt(eb), np.nanmax(np.abs(base - eb))))
check(m > 0.95 and abs(m - em) < 0.01, "metallic %.4f on every texel (mapping %.4f)" % (m, em))
f0 = (1 - m) * 0.08 * s + m * b   # Principled v1's F0 and diffuse, against the program's ks and kd
diffuse = (1 - m) * b
check(np.abs(f0 - ks).max() < 0.02, "Principled's F0 %s = ks %s within 0.02" % (fmt(f0), fmt(ks)))
check(np.abs(diffuse - kd).max() < 0.01, "Principled's diffuse %s = kd %s within 0.01" % (fmt(diffuse), fmt(kd)))
check(addon.rebuild_metals(GOLD, [mat]) == [], "a second rebuild leaves the material alone")

# ---- a red goblet: a dielectric stays as the importer made it -------------------------------------
kd, ks = brdf["red"][:3], brdf["red"][3:6]
raw = import_raw(RED)
red = import_addon(RED)
mat = red.material_slots[0].material
check(mat.get("matlaber_metals") == "dielectric", "red material recognised as dielectric (%s)" % mat.get("matlaber_metals"))
check(graph(mat) == graph(raw.material_slots[0].material), "red material's node graph as the importer's (%d nodes, %d links)"
      % (len(mat.node_tree.nodes), len(mat.node_tree.links)))
b = np.nanmean(bake(red, "Base Color").reshape(-1, 3), axis=0)
m = np.nanmax(bake(red, "Metallic"))
check(np.abs(b - kd).max() < 0.01 and m == 0.0, "red base colour %s = kd %s, metallic %g" % (fmt(b), fmt(kd), m))

# ---- one material mixing both: the mapping is per texel -------------------------------------------
if SPHERE:
    raw = import_raw(SPHERE)
    sph = import_addon(SPHERE)
    check(sph.material_slots[0].material.get("matlaber_metals") == "rebuilt", "sphere material rebuilt")
    kd_tex = bake(raw, "Base Color", 64)
    base, metal = bake(sph, "Base Color", 64), bake(sph, "Metallic", 64)[..., 0]
    left, right = np.s_[:, 4:28], np.s_[:, 36:60]   # texture columns of ks 0.04 and of gold, off the border
    dl = np.nanmax(np.abs(base[left] - kd_tex[left]))
    check(dl < 0.01 and np.nanmax(metal[left]) < 0.005,
          "dielectric half: base colour = kd within %.4f, metallic <= %.4f" % (dl, np.nanmax(metal[left])))
    check(np.nanmin(metal[right]) > 0.3, "gold half: metallic %.2f to %.2f" % (np.nanmin(metal[right]), np.nanmax(metal[right])))
else:
    print("skip: no test_export sphere (one material with dielectric and metal texels)")

# ---- the .glb is read as untrusted input ----------------------------------------------------------
data = open(GOLD, "rb").read()
tmp = os.path.join(os.path.dirname(ZIP), "bad.glb")
for what, blob, message in (("a truncated file", data[:1000], "the header says"),
                            ("a wrong magic", b"glTf" + data[4:], "not a .glb"),
                            ("a JSON chunk past the end", data[:12] + (2 ** 31).to_bytes(4, "little") + data[16:], "does not fit"),
                            ("a JSON chunk that does not parse", data[:20] + b"{" * 8 + data[28:], "does not parse"),
                            ("an empty file", b"", "shorter than")):
    with open(tmp, "wb") as f:
        f.write(blob)
    try:
        addon.read_glb_json(tmp)
        check(False, "%s refused" % what)
    except ValueError as e:
        check(message in str(e), "%s refused: %s" % (what, str(e).replace(tmp, "FILE")))

print("%d failed" % len(failures), flush=True)
sys.exit(1 if failures else 0)
