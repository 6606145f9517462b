"""W7: user equations and recipe loading.

(a) W1 with the gyroid written as an `expr:` equation (data/recipes/gyroid_expr.yaml) against the
    built-in `tpms: gyroid` node (data/recipes/gyroid.yaml), same recipe otherwise; runs alternate,
    three of each, medians compared. Target: equation <= 2x built-in (whole run, and the
    evaluation stages from report.json: solve + evaluate).
(b) Recipe load + validation for a generated recipe of 1,000 field nodes, timed inside one
    process by `voxlat check --repeat` (reading, parameters, key checks, building every node; no
    process start, no evaluation). Target: < 100 ms.
"""
import json
import re
import statistics

from common import ROOT, measure, row, verdict

TITLE = "W7  equation gyroid vs built-in gyroid on W1; load + validation of a 1,000-node recipe"


def _stage_seconds(report):
    t = report["timings_s"]
    return sum(v for k, v in t.items() if k.startswith("solve") or k == "evaluate")


def _generated_recipe(n):
    lines = ["# generated: %d field nodes" % n, "params: {r: 1.5, k: 0.7}", "voxel: 0.5",
             "domain: {box: [[0, 0, 0], [100, 100, 100]]}", "fields:"]
    names = []
    i = 0
    while len(names) < n - 1:
        x, y, z = (i * 7) % 97 + 1.5, (i * 13) % 89 + 2.5, (i * 29) % 83 + 3.5
        kind = i % 4
        name = f"n{i}"
        if kind == 0:
            lines.append(f"  {name}: {{sphere: {{center: [{x}, {y}, {z}], radius: $r}}}}")
        elif kind == 1:
            lines.append(f'  {name}: {{expr: "n{i - 1} + $k*sin(x/3)*cos(y/5)"}}')
        elif kind == 2:
            lines.append(f"  {name}: {{translate: [0.5, 0, -0.25], field: n{i - 1}}}")
        else:
            lines.append(f"  {name}: {{union: [n{i - 1}, n{i - 3}], blend: 0.2}}")
        names.append(name)
        i += 1
    lines.append("  all: {union: [%s]}" % ", ".join(n for n in names if int(n[1:]) % 4 == 3))
    lines.append("result: all")
    return "\n".join(lines) + "\n"


def run(voxlat, tmp):
    times = {"builtin": [], "expr": []}
    peak = {"builtin": 0.0, "expr": 0.0}
    stages = {"builtin": [], "expr": []}
    reports = {}
    for rep in range(3):
        for name, recipe in (("builtin", "gyroid.yaml"), ("expr", "gyroid_expr.yaml")):
            out = tmp / f"{name}{rep}"
            t, m, _ = measure([voxlat, "-q", "run", ROOT / "data/recipes" / recipe, "--out", out])
            times[name].append(t)
            peak[name] = max(peak[name], m)
            reports[name] = json.loads((out / "report.json").read_text())
            stages[name].append(_stage_seconds(reports[name]))
    tb, te = statistics.median(times["builtin"]), statistics.median(times["expr"])
    sb, se = statistics.median(stages["builtin"]), statistics.median(stages["expr"])
    row("built-in gyroid (median of 3)", tb, peak["builtin"])
    row("equation gyroid (median of 3)", te, peak["expr"])
    ratio, stage_ratio = te / tb, se / sb
    print(f"  whole run: equation / built-in = {ratio:.2f}x (target <= 2x: {verdict(ratio <= 2)})")
    print(f"  solve + evaluate stages: {se:.2f}s vs {sb:.2f}s = {stage_ratio:.2f}x (target <= 2x: {verdict(stage_ratio <= 2)})")
    lb, le = reports["builtin"]["fields"]["lattice"], reports["expr"]["fields"]["lattice"]
    print(f"  levels {lb['level']:.12f} vs {le['level']:.12f}; triangles {reports['builtin']['mesh']['triangles']} "
          f"vs {reports['expr']['mesh']['triangles']}")

    recipe = tmp / "generated_1000.yaml"
    recipe.write_text(_generated_recipe(1000))
    _, _, out = measure([voxlat, "check", recipe, "--repeat", "20"])
    m = re.search(r"load \+ validation: ([\d.]+) ms fastest, ([\d.]+) ms median", out)
    fastest, median = float(m.group(1)), float(m.group(2))
    print(f"  1,000-node recipe load + validation (in-process, median of 20): {median:.1f} ms, fastest {fastest:.1f} ms "
          f"(target < 100 ms: {verdict(median < 100)})")
    return {"builtin_s": tb, "expr_s": te, "ratio": ratio, "stage_ratio": stage_ratio,
            "load_1000_median_ms": median, "load_1000_fastest_ms": fastest}
