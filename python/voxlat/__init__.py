"""voxlat from Python: build field graphs, load and save recipes, sample fields on numpy arrays,
run the density solve, get meshes as numpy arrays and write any output format.

A graph built here is a recipe: every node is the same YAML node the command line reads, so a
part made from Python and the same recipe run by `voxlat run` are byte for byte the same.

    import voxlat
    part = voxlat.gyroid(cell=8).sheet(0.3) & voxlat.sphere(radius=20, center=[25, 25, 25])
    recipe = voxlat.Recipe(part, domain=[[0, 0, 0], [50, 50, 50]], voxel=0.2)
    points, triangles = recipe.mesh()

The engine releases the GIL while it works.
"""
import json
import os

import numpy as np

from . import _voxlat as _core
from ._voxlat import Cancelled, InputError, JobError

# An installed package (pip install .) carries its printer profiles and examples in share/voxlat.
_SHARE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "share", "voxlat")
if os.path.isdir(os.path.join(_SHARE, "printers")):
    _core.set_data_folder(_SHARE)

__all__ = [
    "Node", "Recipe", "Cancelled", "InputError", "JobError", "schema", "tpms", "gyroid", "schwarz_p", "schwarz_d", "iwp",
    "neovius", "expr", "vector", "sphere", "box", "cylinder", "mesh", "union", "intersection", "difference", "load",
    "properties",
]


def schema():
    """The recipe language as a JSON Schema (a dict)."""
    return json.loads(_core.schema())


def _spec(value):
    """A node, a field name or a plain value as it is written in a recipe."""
    if isinstance(value, Node):
        return value.spec
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [_spec(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


class Node:
    """A field node: a recipe node spec (a dict) with operators to build graphs.

    a | b union, a & b intersection, a - b difference; .network()/.sheet() cut a raw
    equation or TPMS at a level or a target density; .translate/.rotate/.scale transform.
    A string stands for the field of that name in the recipe.
    """

    def __init__(self, spec):
        self.spec = spec

    def __repr__(self):
        return f"voxlat.Node({json.dumps(self.spec)})"

    def __or__(self, other):
        return union(self, other)

    def __and__(self, other):
        return intersection(self, other)

    def __sub__(self, other):
        return difference(self, other)

    def _solid(self, solid, level, density):
        key = next(iter(self.spec))
        if key not in ("tpms", "expr"):
            raise TypeError(f".{solid}() applies to tpms and expr nodes, not `{key}`")
        spec = dict(self.spec)
        spec["solid"] = solid
        spec.pop("level", None)
        spec.pop("density", None)
        if (level is None) == (density is None):
            raise ValueError("give either a level or density=")
        if level is not None:
            spec["level"] = _spec(level)
        else:
            spec["density"] = _spec(density)
        return Node(spec)

    def network(self, level=None, density=None):
        """The solid f <= level (or the level solved for a relative density)."""
        return self._solid("network", level, density)

    def sheet(self, level=None, density=None):
        """The solid |f| <= level (a wall of half-thickness level in f's units)."""
        return self._solid("sheet", level, density)

    def translate(self, offset):
        return Node({"translate": _spec(offset), "field": self.spec})

    def rotate(self, axis, degrees):
        return Node({"rotate": {"axis": _spec(axis), "degrees": _spec(degrees)}, "field": self.spec})

    def scale(self, factor):
        return Node({"scale": _spec(factor), "field": self.spec})

    def orient(self, along=None, x=None, origin=None):
        """This field with its axes following a frame field: z along `along`, x towards `x`
        (directions: a vector node, a field name or [x, y, z]), turned about `origin`."""
        if along is None and x is None:
            raise ValueError("give along= (the z axis), x= (the x axis) or both")
        frame = {k: _spec(v) for k, v in (("along", along), ("x", x), ("origin", origin)) if v is not None}
        return Node({"orient": frame, "field": self.spec})

    def recipe(self, **kwargs):
        """A recipe whose result is this node (keyword arguments as for Recipe)."""
        return Recipe(self, **kwargs)

    def _probe(self, domain, voxel=None):
        return Recipe(self, domain=domain or [[-1, -1, -1], [1, 1, 1]], voxel=voxel).job().field()

    def values(self, points, domain=None, voxel=None):
        """Values at points (N, 3). A node with density= needs the domain its level is solved in;
        a mesh node needs a domain holding the part and the voxel its distance grid is sampled at."""
        return self._probe(domain, voxel).values(np.asarray(points, dtype=float))

    def gradients(self, points, domain=None, voxel=None):
        """(values (N,), gradients (N, 3)), exact (automatic differentiation)."""
        return self._probe(domain, voxel).gradients(np.asarray(points, dtype=float))


def tpms(kind, cell):
    """A raw TPMS field ("gyroid", "schwarz-p", ...), cell size in mm (or [x, y, z])."""
    return Node({"tpms": kind, "cell": _spec(cell), "solid": "network", "level": 0})


def _tpms_raw(kind):
    def make(cell):
        return Node({"tpms": kind, "cell": _spec(cell)})

    make.__doc__ = f"The {kind} TPMS with this cell size (mm); cut it with .network() or .sheet()."
    return make


gyroid = _tpms_raw("gyroid")
schwarz_p = _tpms_raw("schwarz-p")
schwarz_d = _tpms_raw("schwarz-d")
iwp = _tpms_raw("iwp")
neovius = _tpms_raw("neovius")


def expr(equation):
    """A field given by an equation in x, y, z, $params and field names."""
    return Node({"expr": equation})


def vector(x, y, z):
    """A direction field: three numbers or equations."""
    return Node({"vector": [_spec(x), _spec(y), _spec(z)]})


def sphere(radius, center=(0, 0, 0)):
    return Node({"sphere": {"center": _spec(center), "radius": _spec(radius)}})


def box(lo, hi):
    return Node({"box": [_spec(lo), _spec(hi)]})


def cylinder(radius, height, center=(0, 0, 0), axis=(0, 0, 1)):
    return Node({"cylinder": {"center": _spec(center), "axis": _spec(axis), "radius": radius, "height": height}})


def mesh(path, units=None, repair=False):
    """A part from a closed triangle mesh (.stl, .obj, .ply, .3mf): its signed distance, negative
    inside, on a narrow-band grid at the recipe's voxel. units: the file's unit ("mm", "in", ...);
    repair=True fills small holes. A relative path is made absolute here (against the working
    directory), so the recipe finds the file wherever it is saved."""
    spec = {"mesh": os.path.abspath(os.fspath(path))}
    if units is not None:
        spec["units"] = units
    if repair:
        spec["repair"] = True
    return Node(spec)


def _boolean(kind, nodes, blend):
    spec = {kind: [_spec(n) for n in nodes]}
    if blend:
        spec["blend"] = blend
    return Node(spec)


def union(*nodes, blend=0):
    return _boolean("union", nodes, blend)


def intersection(*nodes, blend=0):
    return _boolean("intersection", nodes, blend)


def difference(*nodes, blend=0):
    return _boolean("difference", nodes, blend)


def _yaml_value(value):
    # JSON is YAML: nested values are written in flow style, exactly as the loader reads them.
    return json.dumps(value)


class Recipe:
    """A recipe: built from a graph (Recipe(node, domain=..., voxel=...)) or loaded from a file.

    fields: extra named fields ({name: Node}); params: {name: default}; outputs: {"mesh": ...}.
    """

    def __init__(self, result=None, domain=None, voxel=0.1, fields=None, params=None, outputs=None, text=None,
                 path=None, sets=(), material=None, properties=None):
        self.sets = list(sets)
        self.path = path
        if text is not None:
            self.text = text
            return
        doc = {}
        if voxel is not None:
            doc["voxel"] = voxel
        elif domain is not None:
            extent = min(h - l for l, h in zip(*domain))
            doc["voxel"] = extent / 8.0  # a probe: no grid is evaluated
        if params:
            doc["params"] = {k: _spec(v) for k, v in params.items()}
        if material is not None:
            doc["material"] = _spec(material)
        if properties is not None:
            doc["properties"] = _spec(properties)
        if domain is not None:
            doc["domain"] = {"box": _spec(domain)}
        named = {k: _spec(v) for k, v in (fields or {}).items()}
        if isinstance(result, Node):
            if "result" in named:
                raise ValueError('Recipe(node, fields={"result": ...}): the name `result` is the node given first; '
                                 'give the other field another name')
            named["result"] = result.spec
            result_name = "result"
        else:
            result_name = result
        doc["fields"] = named
        doc["result"] = result_name
        if outputs:
            doc["outputs"] = outputs
        self.text = self._emit(doc)

    @staticmethod
    def _emit(doc):
        lines = []
        for key, value in doc.items():
            if key in ("fields", "params") and value:
                lines.append(f"{key}:")
                lines += [f"  {json.dumps(k)}: {_yaml_value(v)}" for k, v in value.items()]
            else:
                lines.append(f"{key}: {_yaml_value(value)}")
        return "\n".join(lines) + "\n"

    @classmethod
    def load(cls, path, sets=()):
        """Reads and checks a recipe file (--set style overrides in sets)."""
        _core.Recipe.load(str(path), list(sets))  # check it now: errors name file, line and fix
        with open(path, encoding="utf-8") as f:
            return cls(text=f.read(), path=str(path), sets=sets)

    @classmethod
    def parse(cls, text, sets=()):
        _core.Recipe.parse(text, "<python>", ".", list(sets))
        return cls(text=text, sets=sets)

    def save(self, path):
        """Writes the recipe text; `voxlat run` on the file makes the same part."""
        with open(path, "w", encoding="utf-8") as f:
            f.write(self.text)
        self.path = str(path)

    def core(self, sets=()):
        """The checked engine recipe (voxlat._voxlat.Recipe)."""
        sets = self.sets + list(sets)
        if self.path:
            return _core.Recipe.parse(self.text, self.path, os.path.dirname(os.path.abspath(self.path)), sets)
        return _core.Recipe.parse(self.text, "<python>", ".", sets)

    def canonical(self):
        """The recipe as run (includes merged, parameters applied), as a dict."""
        return self.core().canonical()

    def sha256(self):
        return self.core().sha256()

    def job(self, sets=(), progress=None):
        """A Job: .solve(), .field(name).values(points), .mesh(), .write_mesh(path), .report(),
        .warnings(). `progress(stage, done, total)` is called as its stages advance."""
        return _core.Job(self.core(sets), progress)

    def field(self, name=""):
        return self.job().field(name)

    def mesh(self, tolerance=None, project=None, extractor="marching-cubes"):
        """(points (V, 3) float32, triangles (T, 3) uint32) of the result. tolerance (mm):
        decimated so every point stays within it of the true surface (projection on);
        project=True: vertices moved onto the true surface; extractor: "marching-cubes" or "bcc" (as
        `voxlat mesh --tolerance --project --extractor`)."""
        return self.job().mesh(tolerance=tolerance, project=project, extractor=extractor)

    def run(self, out_dir, progress=None, html=True):
        """Writes the recipe's outputs, report.json and (html) report.html to out_dir; returns the
        report (its `warnings` list holds every warning, as dicts with `code`, `message` and the
        numbers)."""
        job = self.job(progress=progress)
        job.write_outputs(str(out_dir), html=html)
        return job.report()

    def write_mesh(self, path, tolerance=None, project=None, extractor="marching-cubes"):
        """Writes the mesh (.stl, .3mf, .ply, .obj; options as mesh()); returns the report, whose
        `mesh` has the deviation, decimation and topology figures."""
        job = self.job()
        job.write_mesh(str(path), tolerance=tolerance, project=project, extractor=extractor)
        return job.report()


def properties(recipe, sets=(), progress=None):
    """Effective stiffness and conductivity of one periodic cell of the recipe's result (a Recipe
    or a recipe file; it needs `material:`), as `voxlat properties --json` gives them, with the
    tensors as numpy arrays: C_MPa (6, 6), S_per_MPa (6, 6), E_MPa (3,), G_MPa (3,), nu (3, 3),
    E_ratio (3,), conductivity["K_ratio"] (3, 3)."""
    if not isinstance(recipe, Recipe):
        recipe = Recipe.load(recipe)
    p = recipe.job(sets, progress).properties()
    for key in ("C_MPa", "S_per_MPa", "E_MPa", "G_MPa", "nu", "E_ratio", "residual", "iterations"):
        p[key] = np.array(p[key])
    for key in ("K_ratio", "K_W_per_mK"):
        if key in p["conductivity"]:
            p["conductivity"][key] = np.array(p["conductivity"][key])
    return p


def load(path, sets=()):
    """Recipe.load(path, sets)."""
    return Recipe.load(path, sets)
