"""Reading a one-channel EXR (load_exr: the picture tools, tools/vs-mitsuba-picture.py,
side-by-side-picture.py and spp-map-picture.py, and the benchmarks bench-ab, bench-lean and
bench-paper-spp) and setting pictures side by side in a row (row: the first two). Needs
numpy, OpenEXR and Pillow."""
import Imath
import numpy as np
import OpenEXR
from PIL import Image


def load_exr(path):
    """The EXR's Y channel (else R, else its first) as a float32 array of rows."""
    f = OpenEXR.InputFile(path)
    dw = f.header()["dataWindow"]
    w, h = dw.max.x - dw.min.x + 1, dw.max.y - dw.min.y + 1
    channels = f.header()["channels"]
    ch = "Y" if "Y" in channels else ("R" if "R" in channels else next(iter(channels)))
    return np.frombuffer(f.channel(ch, Imath.PixelType(Imath.PixelType.FLOAT)), np.float32).reshape(h, w)


def row(tiles, gap):
    """The tiles (RGB images of one height) left to right, `gap` white pixels apart."""
    out = Image.new("RGB", (sum(t.width for t in tiles) + gap * (len(tiles) - 1), tiles[0].height), (255, 255, 255))
    x = 0
    for t in tiles:
        out.paste(t, (x, 0))
        x += t.width + gap
    return out
