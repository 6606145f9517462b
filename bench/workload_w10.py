"""W10: a build plate of struts. The ELEGOO Saturn 4 (11520 x 5120 pixels, 19 x 24 um), a
200 x 110 x 20 mm BCC strut lattice (2 mm cells, Gaussian kernel sigma 0.2, radii graded from the
centre 0.15 -> 0.3 mm: every strut's weight differs, so no layer or cell repeats) sliced to .goo
with the printability checks on. Targets: <= 10 min and <= 2 GB on the 2-core machine, and the
struts' pixel rate within 10x of a TPMS's on the same window (a gyroid sheet sliced here alongside,
every layer computed: W4's figure).

Measured (2 shared cores at load 5-7: two other engineers building; VOXLAT_W10_HEIGHT=2, so 40
layers and the full plate extrapolated):
- 2026-11-29, plane rows (issue 38): struts 450.5 s, 378 MB, 4.3 Mpixel/s of window; TPMS 13.4 s,
  144 Mpixel/s: 34x (target 10x: missed); full plate 4504 s (target 600 s: missed); info 19.4 s.
- 2026-11-29, plus Taylor sub-samples: struts 335.7 s, 425 MB, 5.8 Mpixel/s; TPMS 13.0 s,
  148.8 Mpixel/s: 26x (missed); full plate 3357 s at that load, about 1250 s on two free cores from
  the CPU time of a 4-layer plate (25.1 s for 193 Mpixel; 211.7 s before issue 38) (missed);
  info 19.8 s, 279 MB.
- 2026-11-29, issue 38 second round (per-strut J tables along the columns, four-lane Gaussian
  recurrences, sub-samples' Gaussians across columns, AVX2 Taylor rows; same archive bytes), at
  load 14-17: VOXLAT_W10_HEIGHT=0.5 (10 layers) struts 328.2 s wall, 402 MB, 1.5 Mpixel/s; TPMS
  15.6 s, 31.0 Mpixel/s: 21x by wall (the load swung during the struts' run); info 97.9 s at that
  load. Side by side by CPU time on 4 layers of the plate (193 Mpixel; /usr/bin/time): before
  27.7 s, after 13.8 s (2.0x), gyroid sheet 1.25 s: struts 11.0x the TPMS per window pixel
  (target 10x: missed); full plate from that CPU time about 690 s on two free cores (target 600 s:
  missed).
Before issue 38 a 20 x 20 x 2 mm window took 32 s for 40 layers and the 2 mm plate did not finish
in ten minutes (the issue's figures).

VOXLAT_W10_HEIGHT (mm, default 20) slices a shorter stack of the same plate (the same window and
struts per layer): the time of the full 20 mm plate is then extrapolated linearly in the layer count
and printed as such. VOXLAT_W10_INFO=0 skips the `voxlat info` timing.
"""
import json
import os

from common import measure, row, verdict

TITLE = "W10 Saturn 4 plate: BCC struts 200 x 110 x 20 mm (2 mm cells, sigma 0.2, radii 0.15-0.3 centred) -> .goo"

STRUTS = """# W10: a plate of graded BCC struts on the Saturn 4
voxel: 0.05
domain: {{box: [[0, 0, 0], [200, 110, {h}]]}}
fields:
  lattice: {{struts: {{cell: bcc, size: 2}}, kernel: {{gaussian: {{sigma: 0.2}}}},
            radius: {{gradient: centred, min: 0.15, max: 0.3}}}}
result: lattice
outputs: {{slices: {{printer: saturn4, layer: 0.05, file: w10.goo, reuse: off}}}}
"""

TPMS = """# W10's TPMS side: W4's gyroid sheet on W10's window, every layer computed
domain: {{box: [[0, 0, 0], [200, 110, {h}]]}}
fields:
  lattice: {{tpms: gyroid, cell: 8, solid: sheet, level: 0.3}}
result: lattice
outputs: {{slices: {{printer: saturn4, layer: 0.05, file: w10-tpms.goo, reuse: off}}}}
"""

FULL_HEIGHT = 20.0


def slice_case(voxlat, tmp, name, text):
    recipe = tmp / f"{name}.yaml"
    recipe.write_text(text)
    t, mb, _ = measure([voxlat, "-q", "run", recipe, "--out", tmp / name, "--no-preview"])
    s = json.loads((tmp / name / "report.json").read_text())["slices"][0]
    return t, mb, s


def run(voxlat, tmp):
    h = float(os.environ.get("VOXLAT_W10_HEIGHT", str(FULL_HEIGHT)))
    print(f"  load average before: {os.getloadavg()[0]:.2f}; stack {h:g} mm of the {FULL_HEIGHT:g} mm plate")
    t_s, mb_s, s = slice_case(voxlat, tmp, "struts", STRUTS.format(h=h))
    t_t, mb_t, st = slice_case(voxlat, tmp, "tpms", TPMS.format(h=h))
    layers, window = s["layers"], s["pixels_total"]
    row(f"voxlat struts, {layers} layers", t_s, mb_s)
    row(f"voxlat gyroid sheet (TPMS), {st['layers']} layers", t_t, mb_t)
    rate_s, rate_t = window / t_s, st["pixels_total"] / t_t
    ratio = rate_t / rate_s
    print(f"  struts {rate_s / 1e6:.1f} Mpixel/s of the window, TPMS {rate_t / 1e6:.1f} Mpixel/s: "
          f"{ratio:.1f}x slower per window pixel (target <= 10x: {verdict(ratio <= 10)})")
    full = t_s * FULL_HEIGHT / h
    how = "measured" if h == FULL_HEIGHT else f"extrapolated from {h:g} mm ({layers} layers) by the layer count"
    print(f"  full 20 mm plate: {full:.0f} s ({how}; target <= 600 s: {verdict(full <= 600)}); "
          f"peak {mb_s:.0f} MB (target <= 2048 MB: {verdict(mb_s <= 2048)})")
    print(f"  exposed volume {s['exposed_volume_mm3']:.1f} mm3; {s['pixels_evaluated'] / window:.1%} of window "
          f"pixels evaluated from the field")
    out = {"struts_s": t_s, "struts_mb": mb_s, "layers": layers, "height_mm": h, "full_plate_s": full,
           "struts_window_pixels_per_s": rate_s, "tpms_s": t_t, "tpms_window_pixels_per_s": rate_t,
           "tpms_over_struts": ratio}
    if os.environ.get("VOXLAT_W10_INFO", "1") != "0":
        recipe = tmp / "info.yaml"
        recipe.write_text(STRUTS.format(h=FULL_HEIGHT))
        t_i, mb_i, text = measure([voxlat, "-q", "info", recipe])
        row("voxlat info (the full 20 mm plate)", t_i, mb_i)
        print("  " + "\n  ".join(line for line in text.strip().splitlines() if line.startswith("result")))
        out.update({"info_s": t_i, "info_mb": mb_i})
    return out
