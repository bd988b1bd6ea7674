# A Cycles picture of a matlaber .glb as the add-on imports it (docs/blender.md), without a window:
#   blender -b --factory-startup --python tools/blender/render_preview.py -- ASSET.glb OUT.png
#           [--before BEFORE.png] [--size 384] [--samples 64]
# --before also renders what Blender's glTF importer alone gives (on Blender < 4.0 a metal loses its
# colour), then the same scene after the add-on's metal rebuild. The camera frames the asset from
# the front (glTF +z, Blender -y), 20 degrees up; light: a grey-white world and a sun. Prints the mean
# colour of the asset's pixels (alpha > 0.5) of each picture. ~5 s at the defaults on 2 cores.
import math
import os
import sys

import bpy
from mathutils import Vector

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import matlaber_blender  # noqa: E402  (the add-on's module, for its rebuild; nothing is registered)


def parse(argv):
    args = {"--before": None, "--size": "384", "--samples": "64"}
    pos = []
    i = 0
    while i < len(argv):
        if argv[i] in args and i + 1 < len(argv):
            args[argv[i]] = argv[i + 1]
            i += 2
        elif argv[i].startswith("--"):
            sys.exit("render_preview.py: unknown option %s" % argv[i])
        else:
            pos.append(argv[i])
            i += 1
    if len(pos) != 2:
        sys.exit("usage: blender -b --python render_preview.py -- ASSET.glb OUT.png [--before BEFORE.png] "
                 "[--size N] [--samples N]")
    return pos[0], pos[1], args["--before"], int(args["--size"]), int(args["--samples"])


def setup(meshes, size, samples):
    sc = bpy.context.scene
    corners = [o.matrix_world @ Vector(c) for o in meshes for c in o.bound_box]
    lo = Vector(tuple(min(c[i] for c in corners) for i in range(3)))
    hi = Vector(tuple(max(c[i] for c in corners) for i in range(3)))
    centre, radius = (lo + hi) / 2, (hi - lo).length / 2
    cam = bpy.data.objects.new("preview_camera", bpy.data.cameras.new("preview_camera"))
    sc.collection.objects.link(cam)
    half = math.atan(cam.data.sensor_width / 2 / cam.data.lens)   # the square picture's half angle
    look = Vector((0.0, 1.0, -math.tan(math.radians(20)))).normalized()
    cam.location = centre - look * (1.05 * radius / math.sin(half))
    cam.rotation_euler = look.to_track_quat("-Z", "Y").to_euler()
    sc.camera = cam
    sun = bpy.data.objects.new("preview_sun", bpy.data.lights.new("preview_sun", "SUN"))
    sun.data.energy = 3.0
    sun.rotation_euler = (math.radians(40), math.radians(15), math.radians(30))
    sc.collection.objects.link(sun)
    world = bpy.data.worlds.new("preview_world")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.6, 0.6, 0.6, 1.0)
    sc.world = world
    sc.render.engine = "CYCLES"
    sc.cycles.device = "CPU"
    sc.cycles.samples = samples
    sc.cycles.use_denoising = False   # Debian's Blender has no OpenImageDenoise (it would fail)
    sc.view_settings.view_transform = "Standard"   # sRGB without Filmic's desaturation, as matlaber's renders
    sc.render.film_transparent = True
    sc.render.resolution_x = sc.render.resolution_y = size
    sc.render.image_settings.file_format = "PNG"
    sc.render.image_settings.color_mode = "RGBA"


def render(path):
    bpy.context.scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(path)
    px = list(img.pixels)
    bpy.data.images.remove(img)
    rgba = [px[i:i + 4] for i in range(0, len(px), 4)]
    inside = [p for p in rgba if p[3] > 0.5]
    mean = [sum(p[c] for p in inside) / max(1, len(inside)) for c in range(3)]
    print("%s: %d asset pixels, mean colour (sRGB, 0-255) %s" % (path, len(inside), " ".join("%.0f" % (255 * v) for v in mean)))
    return mean


def main():
    glb, out, before, size, samples = parse(sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else [])
    try:
        import numpy
        if not hasattr(numpy, "bool"):
            numpy.bool = bool   # Blender 3.4's importer on NumPy >= 1.24, as the add-on does
    except ImportError:
        sys.exit("Blender's glTF importer needs numpy (Debian: apt-get install python3-numpy)")
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    bpy.ops.import_scene.gltf(filepath=os.path.abspath(glb), merge_vertices=True)
    meshes = [o for o in bpy.data.objects if o.type == "MESH"]
    if not meshes:
        sys.exit("%s holds no mesh" % glb)
    setup(meshes, size, samples)
    if before:
        render(os.path.abspath(before))
    mats = {s.material for o in meshes for s in o.material_slots if s.material is not None}
    for name, note in matlaber_blender.rebuild_metals(os.path.abspath(glb), mats):
        print("%s: %s" % (name, note))
    render(os.path.abspath(out))


main()
