"""W5: thickness in millimetres and graded density. The shifted gyroid acceptance recipe
(data/recipes/gyroid-shift.yaml, walls 0.6 mm by gradient shift) side by side with the unshifted
sheet at the same resolution and about the same wall (|f| <= t with t = 0.3 mm x mean |grad f|),
then the graded gyroid (data/recipes/gyroid-graded.yaml) with its per-slab densities."""
import json
import math

from common import ROOT, measure, row, verdict

TITLE = "W5  gyroid sheet 0.6 mm walls by gradient shift vs unshifted sheet; graded gyroid 10 -> 40 %"


def run(voxlat, tmp):
    shift = ROOT / "data/recipes/gyroid-shift.yaml"
    # Same recipe, plain sheet: mean |grad f| on the gyroid is about 1.53 k (reference §1), so
    # t = 0.3 * 1.53 * 2 pi / 8 gives walls of about 0.6 mm on average.
    t = 0.3 * 1.53 * 2 * math.pi / 8
    plain = ["--set", "fields.lattice={tpms: gyroid, cell: 8, solid: sheet, level: %.4f}" % t]
    times = {"shift": [], "plain": []}
    reports = {}
    for _ in range(2):  # alternate, so both see the same machine load
        for name, extra in (("plain", plain), ("shift", [])):
            out = tmp / ("w5-" + name)
            seconds, mb, _ = measure([voxlat, "-q", "run", shift, "--out", out] + extra)
            times[name].append((seconds, mb))
            reports[name] = json.loads((out / "report.json").read_text())
            for f in out.glob("*.stl"):
                f.unlink()  # about 1 GB each
    t_s = min(s for s, _ in times["shift"])
    t_p = min(s for s, _ in times["plain"])
    row("unshifted sheet |f| <= %.3f" % t, t_p, max(m for _, m in times["plain"]))
    row("gradient shift, 0.6 mm walls", t_s, max(m for _, m in times["shift"]))
    ratio = t_s / t_p
    print(f"  shift / plain {ratio:.2f}x (target <= 3x: {verdict(ratio <= 3)})")
    for name in ("plain", "shift"):
        r = reports[name]
        print(f"  {name}: volume fraction {r['result']['volume_fraction']:.4f}, {r['mesh']['triangles']} triangles; "
              + ", ".join(f"{k} {v:.2f}s" for k, v in r["timings_s"].items()))

    graded = ROOT / "data/recipes/gyroid-graded.yaml"
    t_g, m_g, _ = measure([voxlat, "-q", "run", graded, "--out", tmp / "w5-graded"])
    report = json.loads((tmp / "w5-graded" / "report.json").read_text())
    row("graded gyroid 10 -> 40 %, 30 mm", t_g, m_g)
    slabs = report["fields"]["lattice"]["slabs"]
    print("  slabs (target/achieved): " + ", ".join(f"{s['target']:.3f}/{s['achieved']:.3f}" for s in slabs["slabs"]))
    err = slabs["max_abs_error"]
    print(f"  worst slab error {100 * err:.2f} % absolute (target <= 1 %: {verdict(err <= 0.01)})")
    print("  graded stages: " + ", ".join(f"{k} {v:.2f}s" for k, v in report["timings_s"].items()))
    return {"shift_s": t_s, "plain_s": t_p, "ratio": ratio, "graded_s": t_g, "graded_mb": m_g, "slab_error": err}
