"""W4: a 12K-class mono-LCD printer (11520 x 5120 pixels, 19 um) and a 100 mm tall gyroid sheet
(2000 layers of 0.05 mm, 50 x 50 mm footprint), streamed to a zip of PNG layers. It must finish with
memory bounded by a few layers; reports throughput in pixels per second (display pixels written,
and pixels of the part's window decided from the field).

Measured (2 shared cores): 44.1 s, 314 Mpixel/s of the window, 105 MB with every layer computed;
with the layers a z-period (160 layers) above a kept one copied: 10.8-11.2 s, 1238-1280 Mpixel/s
of the window (10.5-10.9 Gpixel/s of display), 176 MB (117 of the 160 phases fit the 64 MiB of
kept images, 1301 layers copied; 33 s with `reuse: off` in the same session). With whole tiles
eight lanes at a time on AVX2 CPUs: 11.47 s, 1208 Mpixel/s of the window, 170 MB; with `reuse: off`
the gain is within the noise (CPU 65.7 -> 62.1 s and 53.5 -> 52.3 s in alternating runs)."""
import json

from common import measure, row, verdict

TITLE = "W4  12K mono-LCD (11520 x 5120, 19 um), gyroid sheet 50 x 50 x 100 mm, 2000 layers -> zip"

RECIPE = """# W4: gyroid sheet, 8 mm cells, 50 x 50 x 100 mm, 12K mono-LCD at 0.05 mm layers
domain: {box: [[0, 0, 0], [50, 50, 100]]}
fields:
  lattice: {tpms: gyroid, cell: 8, solid: sheet, level: 0.3}
result: lattice
outputs: {slices: {printer: mono-12k, layer: 0.05, file: w4.zip, preview: w4-preview.png}}
"""


def run(voxlat, tmp):
    recipe = tmp / "w4.yaml"
    recipe.write_text(RECIPE)
    t, mb, _ = measure([voxlat, "-q", "run", recipe, "--out", tmp / "w4"])
    s = json.loads((tmp / "w4" / "report.json").read_text())["slices"][0]
    layers = s["layers"]
    display = layers * 11520 * 5120
    window = s["pixels_total"]
    row("voxlat (field -> zip of 12K PNGs)", t, mb)
    print(f"  {layers} layers; {display / t / 1e6:.0f} Mpixel/s of display written, "
          f"{window / t / 1e6:.0f} Mpixel/s of the part's window decided; "
          f"{s['pixels_evaluated'] / window:.0%} of window pixels evaluated per pixel, the rest culled by tiles")
    print(f"  peak memory {mb:.0f} MB (bounded: at most {s['max_layers_held']} layers held; "
          f"target < 1024 MB: {verdict(mb < 1024)})")
    return {"seconds": t, "peak_mb": mb, "layers": layers, "display_pixels_per_s": display / t,
            "window_pixels_per_s": window / t, "max_layers_held": s["max_layers_held"]}
