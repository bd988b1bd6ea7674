#!/usr/bin/env python3
# The Blender add-on as the zip Blender's preferences install (Edit > Preferences > Add-ons >
# Install...): matlaber_blender.zip holding matlaber_blender/*.py. Usage: make_zip.py [OUT.zip]
import os
import sys
import zipfile

here = os.path.dirname(os.path.abspath(__file__))
out = sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.getcwd(), "matlaber_blender.zip")
with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
    src = os.path.join(here, "matlaber_blender")
    for name in sorted(os.listdir(src)):
        if name.endswith(".py"):
            z.write(os.path.join(src, name), "matlaber_blender/" + name)
print(out)
