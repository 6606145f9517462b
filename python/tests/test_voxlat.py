"""The Python module: graphs, recipes, sampling with gradients, the density solve, meshes as
numpy arrays, writers, and byte-for-byte agreement with the command line."""
import json
import os
import subprocess
import tempfile
import threading
import time
import unittest
from pathlib import Path

import numpy as np

import voxlat

ROOT = Path(os.environ.get("VOXLAT_SOURCE_DIR", Path(__file__).resolve().parents[2]))
BINARY = os.environ.get("VOXLAT_BINARY", str(ROOT / "build" / "voxlat"))


def gyroid_reference(p, cell):
    k = 2 * np.pi / cell
    x, y, z = (k * p[:, i] for i in range(3))
    value = np.sin(x) * np.cos(y) + np.sin(y) * np.cos(z) + np.sin(z) * np.cos(x)
    grad = k * np.stack([np.cos(x) * np.cos(y) - np.sin(z) * np.sin(x),
                         -np.sin(x) * np.sin(y) + np.cos(y) * np.cos(z),
                         -np.sin(y) * np.sin(z) + np.cos(z) * np.cos(x)], axis=1)
    return value, grad


class VoxlatModule(unittest.TestCase):
    def setUp(self):
        self.tmp = tempfile.TemporaryDirectory(prefix="voxlat-py-")
        self.dir = Path(self.tmp.name)

    def tearDown(self):
        self.tmp.cleanup()

    def test_huge_pages_are_declined_where_the_host_takes_freed_memory_back_and_they_are_slow(self):
        # The module sets the engine's advice as the command line does: on, except where a
        # virtio-balloon device has negotiated free page reporting (feature bit 5, read here from
        # sysfs apart) and its probe did not both fault a huge page in at under half the time of
        # 2 MB of 4 KB pages and take longer for those 4 KB pages than the 4.5 ms a huge page the
        # host must back again costs (kColdHugePageMs in tools/HugePages.h).
        folder = Path("/sys/bus/virtio/drivers/virtio_balloon")
        reported = False
        if folder.is_dir():
            for device in folder.glob("virtio*"):
                try:
                    bits = (device / "features").read_text()
                except OSError:
                    continue
                reported = reported or (len(bits) > 5 and bits[5] == "1")
        huge, small = voxlat._voxlat.huge_page_probe()
        if not reported:
            self.assertEqual((huge, small), (-1.0, -1.0))  # no probe
            self.assertTrue(voxlat._voxlat.huge_page_advice())
        else:
            self.assertGreaterEqual(huge, 0.0)
            self.assertGreaterEqual(small, 0.0)
            self.assertEqual(voxlat._voxlat.huge_page_advice(), 2.0 * huge < small and small > 4.5)

    def test_sampling_values_and_gradients(self):
        rng = np.random.default_rng(3)
        pts = rng.uniform(-20, 20, size=(5000, 3))
        raw = voxlat.gyroid(cell=8).network(level=0)
        values, grads = raw.gradients(pts)
        ref_v, ref_g = gyroid_reference(pts, 8)
        self.assertLess(np.max(np.abs(values - ref_v)), 1e-12)
        self.assertLess(np.max(np.abs(grads - ref_g)), 1e-12)
        eq = voxlat.expr("sin(2*pi*x/8)*cos(2*pi*y/8) + sin(2*pi*y/8)*cos(2*pi*z/8) + sin(2*pi*z/8)*cos(2*pi*x/8)")
        ev, eg = eq.gradients(pts)
        self.assertLess(np.max(np.abs(ev - ref_v)), 1e-12)
        self.assertLess(np.max(np.abs(eg - ref_g)), 1e-12)
        self.assertEqual(eq.values(pts).shape, (5000,))

    def test_graph_operators_match_the_definitions(self):
        rng = np.random.default_rng(4)
        pts = rng.uniform(0, 50, size=(2000, 3))
        part = voxlat.gyroid(cell=8).sheet(0.3) & voxlat.sphere(radius=20, center=[25, 25, 25])
        g, _ = gyroid_reference(pts, 8)
        ball = np.linalg.norm(pts - 25, axis=1) - 20
        np.testing.assert_allclose(part.values(pts), np.maximum(np.abs(g) - 0.3, ball), atol=1e-12)
        cut = voxlat.sphere(radius=10) - voxlat.sphere(radius=5).translate([3, 0, 0])
        a = np.linalg.norm(pts, axis=1) - 10
        b = np.linalg.norm(pts - [3, 0, 0], axis=1) - 5
        np.testing.assert_allclose(cut.values(pts), np.maximum(a, -b), atol=1e-12)

    def test_vector_fields(self):
        rec = voxlat.Recipe("f", domain=[[0, 0, 0], [10, 10, 10]], voxel=0.5,
                            fields={"dir": voxlat.vector("-y", "x", 1), "f": voxlat.expr("dir.x + dir.y")})
        job = rec.job()
        pts = np.array([[1.0, 2.0, 3.0], [4.0, -1.0, 0.5]])
        np.testing.assert_array_equal(job.field("dir").directions(pts), [[-2, 1, 1], [1, 4, 1]])
        np.testing.assert_array_equal(job.field("f").values(pts), [-1, 5])

    def test_orient_follows_a_frame_field(self):
        # Constant directions: the rigid rotation (z axis to y, x axis to z is a turn of -120
        # degrees about [1, 1, 1]); a swirl: the field at q = o + R^T (p - o) by hand.
        g = voxlat.gyroid(cell=6).network(0.1)
        pts = np.random.default_rng(3).uniform(-8, 8, (50, 3))
        turned = g.orient(along=[0, 1, 0], x=[0, 0, 1]).values(pts)
        np.testing.assert_allclose(turned, g.rotate([1, 1, 1], -120).values(pts), atol=1e-12)
        swirled = g.orient(along=voxlat.vector("-y", "x", 5), origin=[1, 2, 3]).values(pts)
        o = np.array([1.0, 2.0, 3.0])
        expected = []
        for p in pts:
            ez = np.array([-p[1], p[0], 5.0])
            ez /= np.linalg.norm(ez)
            ex = np.array([1.0, 0, 0]) - ez[0] * ez
            ex /= np.linalg.norm(ex)
            r = np.column_stack([ex, np.cross(ez, ex), ez])
            expected.append(g.values(np.array([o + r.T @ (p - o)]))[0])
        np.testing.assert_allclose(swirled, expected, atol=1e-12)
        with self.assertRaises(ValueError):
            g.orient(origin=[0, 0, 0])

    def test_recipe_round_trip_and_cli_bytes(self):
        part = voxlat.gyroid(cell=6).sheet(density=0.2) & voxlat.sphere(radius=9, center=[10, 10, 10])
        recipe = voxlat.Recipe(part, domain=[[0, 0, 0], [20, 20, 20]], voxel=0.25, outputs={"mesh": "part.stl"})
        path = self.dir / "part.yaml"
        recipe.save(path)
        loaded = voxlat.Recipe.load(path)
        self.assertEqual(loaded.text, recipe.text)
        self.assertEqual(loaded.sha256(), recipe.sha256())
        # The graph survives the round trip: the canonical copy holds the same nodes.
        canonical = loaded.canonical()
        self.assertEqual(canonical["fields"]["result"]["intersection"][0]["density"], 0.2)
        # The module's mesh and the command line's mesh are the same bytes.
        report = loaded.write_mesh(self.dir / "py.stl")
        subprocess.run([BINARY, "-q", "mesh", str(path), "-o", str(self.dir / "cli.stl")], check=True)
        self.assertEqual((self.dir / "py.stl").read_bytes(), (self.dir / "cli.stl").read_bytes())
        self.assertGreater(report["mesh"]["triangles"], 1000)
        # run() writes the recipe's outputs and report.json like `voxlat run`.
        rep = loaded.run(self.dir / "out")
        subprocess.run([BINARY, "-q", "run", str(path), "--out", str(self.dir / "cli")], check=True)
        self.assertEqual((self.dir / "out/part.stl").read_bytes(), (self.dir / "cli/part.stl").read_bytes())
        cli_report = json.loads((self.dir / "cli/report.json").read_text())
        self.assertEqual(rep["recipe_sha256"], cli_report["recipe_sha256"])

    def test_density_solve_and_mesh_arrays(self):
        recipe = voxlat.Recipe(voxlat.gyroid(cell=5).network(density=0.3), domain=[[0, 0, 0], [10, 10, 10]], voxel=0.2)
        job = recipe.job()
        job.solve()
        report = job.report()
        self.assertAlmostEqual(report["fields"]["result"]["achieved_density"], 0.3, delta=0.002)
        points, triangles = job.mesh()
        report = job.report()
        self.assertEqual(points.dtype, np.float32)
        self.assertEqual(points.shape[1], 3)
        self.assertEqual(triangles.shape, (job.report()["mesh"]["triangles"], 3))
        self.assertLess(int(triangles.max()), len(points))
        # Closed, outward mesh: the divergence-theorem volume matches the report.
        p = points.astype(np.float64)[triangles]
        volume = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6
        self.assertAlmostEqual(volume, report["mesh"]["volume_mm3"], delta=1e-6 * abs(volume))
        for ext in ("ply", "obj", "stl"):
            job.write_mesh(str(self.dir / f"m.{ext}"))
            self.assertGreater((self.dir / f"m.{ext}").stat().st_size, 1000)

    def test_mesh_options_tolerance_and_projection(self):
        # A ball of radius 5: the decimated mesh keeps every point within the tolerance of the
        # true sphere (measured here from |p| - 5, not by the engine), is closed (every edge in
        # exactly two triangles) and has far fewer triangles than marching cubes' mesh.
        recipe = voxlat.Recipe(voxlat.sphere(5), domain=[[-8, -8, -8], [8, 8, 8]], voxel=0.25)
        raw_points, raw_triangles = recipe.mesh()
        projected, _ = recipe.mesh(project=True)
        raw_off = np.abs(np.linalg.norm(raw_points.astype(np.float64), axis=1) - 5).max()
        on_off = np.abs(np.linalg.norm(projected.astype(np.float64), axis=1) - 5).max()
        self.assertLess(on_off, 0.01 * 0.25)
        self.assertLess(on_off, raw_off)
        tolerance = 0.02
        points, triangles = recipe.mesh(tolerance=tolerance)
        self.assertLess(len(triangles), len(raw_triangles) / 3)
        p = points.astype(np.float64)[triangles]
        w = np.array([[a, b, 1 - a - b] for a in np.linspace(0, 1, 7) for b in np.linspace(0, 1, 7) if a + b <= 1])
        samples = np.einsum("sk,tkd->tsd", w, p).reshape(-1, 3)
        self.assertLess(np.abs(np.linalg.norm(samples, axis=1) - 5).max(), tolerance)
        edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
        _, counts = np.unique(edges, axis=0, return_counts=True)
        self.assertTrue((counts == 2).all())
        report = recipe.write_mesh(self.dir / "ball.stl", tolerance=tolerance)
        self.assertEqual(report["mesh"]["triangles"], len(triangles))
        self.assertLessEqual(report["mesh"]["deviation"]["max_mm"], tolerance)
        with self.assertRaises(ValueError) as e:
            recipe.mesh(tolerance=0)
        self.assertIn("tolerance=", str(e.exception))
        # The BCC extractor: a closed mesh of the same ball, its vertices on the sphere when projected.
        bcc_points, bcc_triangles = recipe.mesh(project=True, extractor="bcc")
        self.assertGreater(len(bcc_triangles), len(raw_triangles))
        self.assertLess(np.abs(np.linalg.norm(bcc_points.astype(np.float64), axis=1) - 5).max(), 0.01 * 0.25)
        edges = np.sort(np.concatenate([bcc_triangles[:, [0, 1]], bcc_triangles[:, [1, 2]],
                                        bcc_triangles[:, [2, 0]]]), axis=1)
        _, counts = np.unique(edges, axis=0, return_counts=True)
        self.assertTrue((counts == 2).all())
        with self.assertRaises(ValueError) as e:
            recipe.mesh(extractor="dual-contouring")
        self.assertIn("bcc", str(e.exception))

    def test_progress_callback_and_warnings_list(self):
        # Walls of 1.2 mm in an 8 mm gyroid cell: 15 % of the cell, past the uniform-shift range.
        recipe = voxlat.Recipe.parse("voxel: 0.5\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nfields:\n"
                                     "  s: {tpms: gyroid, cell: 8, solid: sheet, thickness: 1.2}\nresult: s\n")
        calls = []
        job = recipe.job(progress=lambda stage, done, total: calls.append((stage, done, total)))
        job.mesh()
        stages = {stage for stage, _, _ in calls}
        self.assertIn("meshing", stages)
        for stage, done, total in calls:
            self.assertLessEqual(done, total)
        # Each stage reports its completion last.
        self.assertTrue(any(s == "meshing" and d == t for s, d, t in calls))
        warnings = job.warnings()
        thick = [w for w in warnings if w["code"] == "thick_walls"]
        self.assertEqual(len(thick), 1)
        self.assertAlmostEqual(thick[0]["wall_mm"], 1.2)
        self.assertIn("15 %", thick[0]["message"])
        self.assertEqual(job.report()["warnings"][0]["code"], "thick_walls")

    def test_params_and_sets(self):
        recipe = voxlat.Recipe(voxlat.Node({"tpms": "gyroid", "cell": "$cell", "solid": "sheet", "level": "$t"}),
                               domain=[[0, 0, 0], [8, 8, 8]], voxel=0.5, params={"cell": 4, "t": 0.3})
        pts = np.array([[1.0, 2.0, 3.0]])
        a = recipe.job().field().values(pts)
        b = recipe.job(sets=["cell=8"]).field().values(pts)
        g4, _ = gyroid_reference(pts, 4)
        g8, _ = gyroid_reference(pts, 8)
        np.testing.assert_allclose(a, np.abs(g4) - 0.3, atol=1e-12)
        np.testing.assert_allclose(b, np.abs(g8) - 0.3, atol=1e-12)
        with self.assertRaises(voxlat.InputError) as e:
            recipe.job(sets=["cell=abc"])
        self.assertIn("expected a number like its default", str(e.exception))

    def test_errors_are_input_errors(self):
        with self.assertRaises(voxlat.InputError) as e:
            voxlat.expr("sin(x) + (y").values(np.zeros((1, 3)))
        self.assertIn("expected `)`", str(e.exception))
        self.assertIn("^", str(e.exception))
        with self.assertRaises(voxlat.InputError):
            voxlat.Recipe.load(self.dir / "missing.yaml")
        with self.assertRaises(ValueError):
            voxlat.expr("x").values(np.zeros((4, 2)))

    def test_schema(self):
        s = voxlat.schema()
        self.assertIn("node_expr", s["$defs"])
        self.assertEqual(set(s["$defs"]["node_expr"]["properties"]), {"expr", "solid", "level", "density", "offset"})

    def test_gil_is_released_while_the_engine_works(self):
        # A box of whole cells would solve on one period in milliseconds: 31 mm makes the solve
        # count the whole box, long enough to see the ticker run beside it.
        recipe = voxlat.Recipe(voxlat.gyroid(cell=5).network(density=0.3), domain=[[0, 0, 0], [31, 31, 31]], voxel=0.1)
        ticks = []
        done = threading.Event()

        def ticker():
            while not done.is_set():
                ticks.append(time.perf_counter())
                time.sleep(0.005)

        t = threading.Thread(target=ticker)
        t.start()
        start = time.perf_counter()
        recipe.job().solve()
        elapsed = time.perf_counter() - start
        done.set()
        t.join()
        during = [x for x in ticks if start < x < start + elapsed]
        # With the GIL held the ticker could not run at all while the solve works.
        self.assertGreater(elapsed, 0.05)
        self.assertGreater(len(during), 3)

    def _slow_recipe(self):
        # The whole 31 mm box counted by the solve: long enough (a second or more) to stop halfway.
        return voxlat.Recipe(voxlat.gyroid(cell=5).network(density=0.3), domain=[[0, 0, 0], [31, 31, 31]], voxel=0.1)

    def test_a_progress_callback_exception_is_raised_after_a_clean_cancel(self):
        # Issue 40: any exception in progress= aborted the interpreter (SIGABRT).
        def bad(stage, done, total):
            raise ZeroDivisionError("from the callback")
        job = self._slow_recipe().job(progress=bad)
        with self.assertRaises(ZeroDivisionError):
            job.solve()
        wrong_signature = self._slow_recipe().job(progress=lambda: None)
        with self.assertRaises(TypeError):
            wrong_signature.solve()
        with self.assertRaises(TypeError):
            self._slow_recipe().job(progress=5)
        exits = self._slow_recipe().job(progress=lambda *a: (_ for _ in ()).throw(SystemExit(4)))
        with self.assertRaises(SystemExit):
            exits.mesh()

    def test_keyboard_interrupt_cancels_a_running_job(self):
        import _thread
        job = self._slow_recipe().job()
        timer = threading.Timer(0.2, _thread.interrupt_main)
        start = time.perf_counter()
        timer.start()
        with self.assertRaises(KeyboardInterrupt):
            job.mesh()
        elapsed = time.perf_counter() - start
        timer.join()
        # Whole job: several seconds; the interrupt lands within a few tenths of its arrival.
        self.assertLess(elapsed, 2.0)
        out = self.dir / "out"
        self.assertFalse(out.exists())

    def test_a_job_refuses_a_second_thread_while_it_runs(self):
        job = self._slow_recipe().job()
        errors = []

        def second():
            time.sleep(0.1)
            try:
                job.report()
            except RuntimeError as e:
                errors.append(str(e))

        t = threading.Thread(target=second)
        t.start()
        job.mesh()
        t.join()
        self.assertEqual(len(errors), 1)
        self.assertIn("running in another thread", errors[0])
        self.assertIn("fields", job.report())  # free again once the call returned

    def test_recipe_result_name_is_not_dropped(self):
        with self.assertRaises(ValueError):
            voxlat.Recipe(voxlat.sphere(radius=1), fields={"result": voxlat.sphere(radius=2)}, voxel=0.5)

    def test_mesh_node_signed_distance_of_the_bracket(self):
        # data/meshes/bracket.stl: an L of 5 mm plates, base y 0-24 z 0-5, upright y 0-5 z 0-24,
        # x 0-30, a 3 mm fillet in the inner corner (centre y = z = 8) and 2.5 mm holes through
        # the base at x = 7.5, 22.5, y = 16. Distances are exact within 3 voxels of the surface.
        bracket = ROOT / "data/meshes/bracket.stl"
        part = voxlat.mesh(bracket)
        self.assertEqual(part.spec, {"mesh": str(bracket.resolve())})
        self.assertEqual(voxlat.mesh("part.stl", units="in").spec,
                         {"mesh": os.path.join(os.getcwd(), "part.stl"), "units": "in"})
        recipe = voxlat.Recipe(part, domain=[[-2, -2, -2], [32, 26, 26]], voxel=0.5)
        field = recipe.field()
        exact = {  # point: signed distance (negative inside)
            (15, 12, 4.0): -1.0,        # base, 1 mm under its top face
            (15, 12, 5.6): 0.6,         # above the base
            (15, 12, -0.8): 0.8,        # below it
            (-0.7, 12, 2.5): 0.7,       # off the end face x = 0
            (15, 4.0, 12): -1.0,        # upright, 1 mm inside its face y = 5
            (7.5, 17.5, 2.5): 1.0,      # in a hole, 1 mm from its wall
            (7.5, 19.0, 2.5): -0.5,     # in the base, 0.5 mm from the same hole
            (15, 6.5, 6.5): 3 - 1.5 * np.sqrt(2),     # inside the fillet's circle (air), on its bisector
            (15, 8 - 3.5 / np.sqrt(2), 8 - 3.5 / np.sqrt(2)): -0.5,  # in the fillet, 0.5 mm from its arc
        }
        pts = np.array(list(exact), dtype=float)
        np.testing.assert_allclose(field.values(pts), list(exact.values()), atol=0.08)
        # Beyond the band the value is clamped but keeps its sign.
        far = np.array([[15, 12, 2.5], [7.5, 16, 2.5], [15, 20, 15], [15, 2.5, 20]], dtype=float)
        self.assertEqual(list(np.sign(field.values(far))), [-1, 1, 1, -1])
        # The tutorial's part: a gyroid sheet clipped to the mesh, meshed in an automatic domain.
        lattice = voxlat.gyroid(cell=8).sheet(0.3)
        clipped = voxlat.Recipe(lattice & part, voxel=0.5)
        g, _ = gyroid_reference(pts, 8)
        np.testing.assert_allclose(clipped.field().values(pts), np.maximum(np.abs(g) - 0.3, field.values(pts)),
                                   atol=1e-6)
        points, _ = clipped.mesh()
        self.assertGreater(len(points), 1000)
        self.assertTrue(np.all(points.min(axis=0) > -0.5) and np.all(points.max(axis=0) < [30.5, 24.5, 24.5]))

    def test_properties_as_numpy_arrays(self):
        # Square columns of side 1 mm along z in a 2 mm cell: E_z = E_s / 4, nothing across.
        column = voxlat.box([0.5, 0.5, -1], [1.5, 1.5, 3])
        recipe = voxlat.Recipe(column, voxel=0.125, material={"E": "2 GPa", "nu": 0.3},
                               properties={"cell": [2, 2, 2], "origin": [0, 0, 0], "resolution": 16})
        p = voxlat.properties(recipe)
        self.assertEqual(p["C_MPa"].shape, (6, 6))
        np.testing.assert_allclose(p["E_MPa"], [0.0, 0.0, 500.0], atol=1e-6 * 2000)
        np.testing.assert_allclose(p["C_MPa"], p["C_MPa"].T, atol=1e-9 * 2000)
        self.assertAlmostEqual(p["relative_density"], 0.25)

    def test_example_scripts_run(self):
        for script in sorted((ROOT / "data/scripts").glob("*.py")):
            with self.subTest(script=script.name):
                out = subprocess.run(["/usr/bin/python3", str(script), str(self.dir / script.stem)], capture_output=True,
                                     text=True, env=dict(os.environ))
                self.assertEqual(out.returncode, 0, out.stdout + out.stderr)


if __name__ == "__main__":
    unittest.main()
