#!/usr/bin/env python3
"""Decodes every PNG of two slice archives (.sl1/.sl1s/.zip or folders) and compares the pixels,
to show that a change of the slicer or of the PNG encoder left the images as they were.

  /usr/bin/python3 bench/compare_slices.py OLD.sl1s NEW.sl1s

Compares the layer images, and the thumbnails, pixel by pixel (PIL decodes them: an independent
decoder, as a printer's), reports whether the encoded bytes are also the same and exits 1 on the
first image whose pixels differ or when the two hold different image names."""
import io
import pathlib
import sys
import zipfile

import numpy as np
from PIL import Image


def images(path):
    """name -> encoded bytes of every PNG in the archive or folder."""
    path = pathlib.Path(path)
    if path.is_dir():
        return {p.relative_to(path).as_posix(): p.read_bytes() for p in sorted(path.rglob("*.png"))}
    with zipfile.ZipFile(path) as z:
        return {n: z.read(n) for n in sorted(z.namelist()) if n.endswith(".png")}


def pixels(data):
    image = Image.open(io.BytesIO(data))
    image.load()
    return image.mode, np.asarray(image)


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    old, new = images(sys.argv[1]), images(sys.argv[2])
    if sorted(old) != sorted(new):
        print(f"different images: {sorted(set(old) ^ set(new))[:5]}")
        return 1
    same_bytes = 0
    for name in sorted(old):
        if old[name] == new[name]:
            same_bytes += 1
            continue
        (mode_a, a), (mode_b, b) = pixels(old[name]), pixels(new[name])
        if mode_a != mode_b or a.shape != b.shape or not np.array_equal(a, b):
            diff = "" if a.shape != b.shape else f", {np.count_nonzero(a != b)} values differ"
            print(f"{name}: pixels differ ({mode_a} {a.shape} vs {mode_b} {b.shape}{diff})")
            return 1
    # Images with the same bytes decode to the same pixels; decode one anyway so a broken archive fails.
    for name in sorted(old)[:1]:
        pixels(new[name])
    print(f"{len(old)} images, same pixels; {same_bytes} byte-identical, {len(old) - same_bytes} re-encoded")
    return 0


if __name__ == "__main__":
    sys.exit(main())
