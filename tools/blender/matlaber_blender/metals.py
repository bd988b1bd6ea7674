# Metals of a matlaber .glb rebuilt for Blender's Principled BSDF before 4.0, after the glTF
# importer (docs/blender.md, "Metals"); the add-on (__init__.py) calls rebuild_metals after an import.
import json
import math
import os
import re
import struct

import bpy

# ---- metals on Blender's Principled BSDF before 4.0 ---------------------------------------------
# The program's BRDF (docs/export.md) is diffuse kd + GGX specular with a coloured F0 = ks; the .glb
# carries ks in KHR_materials_specular over metallic 0. Principled BSDF v1 (Blender < 4.0) has
#   diffuse = (1 - Metallic) Base,   F0 = (1 - Metallic) 0.08 Specular + Metallic Base
# (Specular Tint only tints towards the base colour), so Blender 3.x's importer makes ks a grey
# Specular tinted towards kd: a metal (dark kd, bright coloured ks) loses its colour, a gold goblet
# renders dark red (docs/blender.md). The rebuild solves for
# Base, Metallic m and Specular per texel, with shader nodes on the imported textures:
#   d = min(min_c ks, 0.08): the grey part of F0 a dielectric specular holds (0.08 = Specular 1);
#   m = clamp((max ks - d) / (max(kd + ks) - d)): the share of the brightest channel's reflectance
#       (diffuse + F0) that is F0 beyond d, i.e. metal;
#   Base = kd + ks - (1 - m) d, so that diffuse + F0 = kd + ks in every channel (until Base reaches
#       1), and on the brightest channel F0 = ks - m (1 - m) d, diffuse = kd + m (1 - m) d: within
#       d / 4 <= 0.02 of the program's; Specular = d / 0.08.
# A dielectric texel (grey ks = d) gets m = 0, Base = kd and Specular = ks / 0.08, what the importer
# gives; a metal (kd ~ 0) gets m ~ 1 and Base ~ ks. Materials without a metal texel are left as
# imported.
GLB_MAGIC, GLB_JSON = 0x46546C67, 0x4E4F534A
GLB_JSON_MAX = 64 << 20       # far above any JSON the program writes (a few KB)
DIELECTRIC_F0_MAX = 0.08      # Principled v1's Specular 1; common dielectrics lie in 0.02-0.08
METAL_MIN = 0.02              # F0 beyond the dielectric's that counts as metal: 8-bit sRGB noise is ~0.001


def read_glb_json(path):
    """The JSON chunk of a .glb as a dict. The file is untrusted: magic, version, the header's length
    against the file's and the chunk's bounds are checked; ValueError names the problem."""
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        head = f.read(20)
        if len(head) < 20:
            raise ValueError("%s: %d bytes, shorter than a .glb header" % (path, len(head)))
        magic, version, length, n, kind = struct.unpack("<5I", head)
        if magic != GLB_MAGIC:
            raise ValueError("%s: not a .glb (magic 0x%08x)" % (path, magic))
        if version != 2:
            raise ValueError("%s: glTF container version %d (2 expected)" % (path, version))
        if length != size:
            raise ValueError("%s: the header says %d bytes, the file has %d" % (path, length, size))
        if kind != GLB_JSON:
            raise ValueError("%s: the first chunk is not JSON (type 0x%08x)" % (path, kind))
        if n > length - 20 or n > GLB_JSON_MAX:
            raise ValueError("%s: a JSON chunk of %d bytes does not fit in %d" % (path, n, length))
        data = f.read(n)
    if len(data) != n:
        raise ValueError("%s: the JSON chunk is cut short" % path)
    try:
        root = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as e:
        raise ValueError("%s: the JSON chunk does not parse (%s)" % (path, e))
    if not isinstance(root, dict):
        raise ValueError("%s: the JSON chunk is not an object" % path)
    return root


def _entry(root, key, i):
    """root[key][i] when it is a dict, else None (indices come from the file)."""
    seq = root.get(key)
    if isinstance(seq, list) and isinstance(i, int) and not isinstance(i, bool) and 0 <= i < len(seq) \
            and isinstance(seq[i], dict):
        return seq[i]
    return None


def _number(v, default):
    if v is None:
        return default
    if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
        return float(v)
    raise ValueError("not a finite number: %r" % (v,))


def specular_materials(root):
    """{name: (ks image name or None, F0 scale (r, g, b), specularFactor)} for the materials whose F0 is
    KHR_materials_specular's over metallic 0 (docs/export.md: F0 = min(0.04 scale tex, 1) factor);
    entries that are malformed or mean something else are left out."""
    out = {}
    mats = root.get("materials")
    for i in range(len(mats) if isinstance(mats, list) else 0):
        m = _entry(root, "materials", i)
        try:
            pbr = m.get("pbrMetallicRoughness", {})
            ext = m.get("extensions", {}).get("KHR_materials_specular")
            name = m.get("name")
            if not isinstance(name, str) or not isinstance(pbr, dict) or not isinstance(ext, dict):
                continue
            if _number(pbr.get("metallicFactor"), 1.0) != 0.0:   # glTF's default is 1: a metal already
                continue
            factor = _number(ext.get("specularFactor"), 1.0)
            color = ext.get("specularColorFactor", [1.0, 1.0, 1.0])
            if not isinstance(color, list) or len(color) != 3:
                continue
            scale = tuple(0.04 * _number(c, 1.0) for c in color)
            if factor < 0 or min(scale) < 0:
                continue
            image = None
            tex = ext.get("specularColorTexture")
            if tex is not None:
                t = _entry(root, "textures", tex.get("index") if isinstance(tex, dict) else None)
                im = _entry(root, "images", t.get("source")) if t else None
                if im is None or not isinstance(im.get("name"), str):
                    continue
                image = im["name"]
            out[name] = (image, scale, factor)
        except (AttributeError, ValueError):
            continue
    return out


def _principled_v1(bsdf):
    """Principled BSDF before Blender 4.0: a scalar Specular Tint, so no coloured F0 below Metallic."""
    i = bsdf.inputs
    return all(n in i for n in ("Base Color", "Metallic", "Specular", "Specular Tint")) and i["Specular Tint"].type == "VALUE"


def _image_node(tree, name):
    """The importer's image node of the glTF image `name` (Blender adds .001 on a name clash)."""
    pat = re.compile(re.escape(name) + r"(\.\d{3,})?")
    found = [n for n in tree.nodes if n.type == "TEX_IMAGE" and n.image is not None and pat.fullmatch(n.image.name)]
    return found[0] if len(found) == 1 else None


def _linear_rgb(image):
    """An image's texels as linear RGB, [N, 3] (Image.pixels gives 8-bit images still encoded)."""
    import numpy as np
    a = np.empty(len(image.pixels), np.float32)
    image.pixels.foreach_get(a)
    a = a.reshape(-1, image.channels)[:, :3]
    if not image.is_float and image.colorspace_settings.name == "sRGB":
        a = np.where(a <= 0.04045, a / 12.92, ((a + 0.055) / 1.055) ** 2.4)
    return a


def _rebuild(mat, bsdf, ks_out, scale, factor):
    """The nodes of the mapping above, between the imported kd / ks and the Principled BSDF."""
    nt = mat.node_tree
    nodes, links = nt.nodes, nt.links
    frame = nodes.new("NodeFrame")
    frame.label = "matlaber: F0 (ks) to Metallic and Base Color"
    x0, y0 = bsdf.location.x - 1400, bsdf.location.y - 700
    count = [0]

    def new(kind, op=None, *args, clamp=False):
        n = nodes.new(kind)
        n.parent = frame
        n.location = (x0 + 180 * (count[0] % 7), y0 - 200 * (count[0] // 7))
        count[0] += 1
        if op:
            n.operation = op
        if clamp:
            n.use_clamp = True
        for sock, v in zip(n.inputs, args):
            if isinstance(v, bpy.types.NodeSocket):
                links.new(v, sock)
            elif sock.type == "VECTOR":
                sock.default_value = v if isinstance(v, tuple) else (v, v, v)
            else:
                sock.default_value = v
        return n

    def math(op, a, b, clamp=False):
        return new("ShaderNodeMath", op, a, b, clamp=clamp).outputs[0]

    def vec(op, a, b):
        return new("ShaderNodeVectorMath", op, a, b).outputs[0]

    def channels(v, op):
        s = new("ShaderNodeSeparateXYZ", None, v).outputs
        return math(op, math(op, s[0], s[1]), s[2])

    base_in = bsdf.inputs["Base Color"]
    kd = base_in.links[0].from_socket if base_in.is_linked else tuple(base_in.default_value[:3])
    ks = ks_out
    if isinstance(ks, bpy.types.NodeSocket) and any(abs(c - 1.0) > 1e-6 for c in scale):
        ks = vec("MINIMUM", vec("MULTIPLY", ks, scale), (1.0, 1.0, 1.0))
    if isinstance(ks, bpy.types.NodeSocket) and abs(factor - 1.0) > 1e-6:
        ks = vec("MULTIPLY", ks, (factor,) * 3)
    d = math("MINIMUM", channels(ks, "MINIMUM"), DIELECTRIC_F0_MAX)
    total = vec("ADD", kd, ks)
    # max ks <= max(kd + ks), so 0 <= m <= 1; Blender's divide gives 0 for 0/0 (a black texel)
    m = math("DIVIDE", math("SUBTRACT", channels(ks, "MAXIMUM"), d), math("SUBTRACT", channels(total, "MAXIMUM"), d),
             clamp=True)
    base = vec("MINIMUM", vec("SUBTRACT", total, math("MULTIPLY", math("SUBTRACT", 1.0, m), d)), (1.0, 1.0, 1.0))
    specular = math("MULTIPLY", d, 1.0 / 0.08)

    replaced = []
    for name in ("Base Color", "Metallic", "Specular", "Specular Tint"):
        for link in list(bsdf.inputs[name].links):
            replaced.append(link.from_node)
            links.remove(link)
    links.new(base, base_in)
    links.new(m, bsdf.inputs["Metallic"])
    links.new(specular, bsdf.inputs["Specular"])
    bsdf.inputs["Specular Tint"].default_value = 0.0
    # the importer's Specular / Specular Tint images and the Metallic factor now feed nothing
    for n in set(replaced):
        if n.name in nodes and not any(o.is_linked for o in n.outputs) and n.type not in ("GROUP", "OUTPUT_MATERIAL"):
            image = n.image if n.type == "TEX_IMAGE" else None
            nodes.remove(n)
            if image is not None and image.users == 0:
                bpy.data.images.remove(image)
    mat["matlaber_metals"] = "rebuilt"


def rebuild_metals(glb, materials):
    """Rebuilds the imported materials of glb whose metals Blender's Principled BSDF would render dark
    (see above). Returns [(material name, what was done)]."""
    root = read_glb_json(glb)
    spec = specular_materials(root)
    notes = []
    for mat in sorted(materials, key=lambda m: m.name):
        if mat.get("matlaber_metals") or not mat.use_nodes:
            continue
        keys = [k for k in spec if mat.name == k or re.fullmatch(re.escape(k) + r"\.\d{3,}", mat.name)]
        if len(keys) != 1:
            continue   # not a material with F0 in KHR_materials_specular
        image_name, scale, factor = spec[keys[0]]
        bsdf = next((n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED"), None)
        if bsdf is None:
            notes.append((mat.name, "metals not rebuilt: no Principled BSDF"))
            continue
        if not _principled_v1(bsdf):
            continue   # Principled v2 (Blender 4.0+): a colour Specular Tint, which the importer fills with ks
        import numpy as np
        if image_name is None:
            ks_out = tuple(min(c, 1.0) * factor for c in scale)
            ks = np.array([ks_out], np.float32)
        else:
            node = _image_node(mat.node_tree, image_name)
            if node is None:
                notes.append((mat.name, "metals not rebuilt: no image node of '%s'" % image_name))
                continue
            ks_out = node.outputs["Color"]
            ks = np.minimum(_linear_rgb(node.image) * np.array(scale, np.float32), 1.0) * factor
        excess = ks.max(axis=1) - np.minimum(ks.min(axis=1), DIELECTRIC_F0_MAX)
        if float(excess.max(initial=0.0)) <= METAL_MIN:
            mat["matlaber_metals"] = "dielectric"
            notes.append((mat.name, "dielectric, kept as imported"))
            continue
        _rebuild(mat, bsdf, ks_out, scale, factor)
        notes.append((mat.name, "metal texels rebuilt for Principled BSDF (%.0f%% of the texels)"
                      % (100.0 * float((excess > METAL_MIN).mean()))))
    return notes
