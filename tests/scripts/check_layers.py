#!/usr/bin/env python3
"""The build's layering rule, checked on every #include: a folder may include only from itself and
from the folders below it (docs/architecture.md). A new folder must be added here, with its place.
Also: jobs receive the recipe's settings parsed (typed structs); no file of engine/jobs/ reads a
recipe's YAML node (printer profiles, files of their own, are loaded in PrinterProfile.cpp)."""
import pathlib
import re
import sys

# folder -> the folders it may include from (besides itself). Lower layers first.
# fields/ by family: core below everything; frames and levels build on the families they compose.
FIELDS = ["fields/core", "fields/tpms", "fields/struts", "fields/expr", "fields/shapes", "fields/maps",
          "fields/frames", "fields/levels"]
# The mesher's grid -> mesh stages (one library, voxlat_extract), in the order a mesh passes them.
MESH = ["mesher/extract", "mesher/checks", "mesher/tolerance", "mesher/clip"]
ALLOWED = {
    "fields/core": [],
    "fields/tpms": ["fields/core"],
    "fields/struts": ["fields/core"],
    "fields/expr": ["fields/core"],
    "fields/shapes": ["fields/core"],
    "fields/maps": ["fields/core"],
    "fields/frames": ["fields/core", "fields/expr", "fields/maps"],
    "fields/levels": ["fields/core", "fields/maps", "fields/shapes", "fields/tpms"],
    "mesher/extract": FIELDS,
    "mesher/checks": FIELDS + MESH[:1],
    "mesher/tolerance": FIELDS + MESH[:2],
    "mesher/clip": FIELDS + MESH[:3],
    "mesher/slice": FIELDS,
    "mesher/writers": FIELDS + MESH + ["mesher/slice"],
    "engine/core": FIELDS,
    "engine/density": FIELDS + ["engine/core"],
    "engine/frames": FIELDS + ["engine/core"],
    "engine/parts": FIELDS + MESH + ["engine/core"],
    "engine/properties": FIELDS + ["engine/core"],
    "engine/checks": FIELDS + MESH + ["mesher/slice", "engine/core"],  # pieces, printability
    "engine/recipe": FIELDS + MESH + ["engine/core", "engine/density", "engine/frames", "engine/parts"],
    "engine/jobs": FIELDS + MESH + ["mesher/slice", "mesher/writers", "engine/core", "engine/density",
                                    "engine/frames", "engine/parts", "engine/properties", "engine/checks",
                                    "engine/recipe"],
}
INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.M)
YAML_READ = re.compile(r"\bYAML::|\bRecipeNode\b|\.root\[")
YAML_LOADERS = {"engine/jobs/PrinterProfile.cpp"}


def folder_of(path: str) -> str:
    return "/".join(path.split("/")[:2])


def main() -> int:
    root = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else ".")
    bad = []
    for top in ("fields", "mesher", "engine"):
        for f in sorted((root / top).rglob("*")):
            if f.suffix not in (".h", ".cpp"):
                continue
            rel = f.relative_to(root).as_posix()
            own = folder_of(rel)
            if own not in ALLOWED:
                bad.append(f"{rel}: folder {own} has no place in the layer table (tests/scripts/check_layers.py)")
                continue
            for inc in INCLUDE.findall(f.read_text()):
                target = folder_of(inc)
                if target != own and target not in ALLOWED[own] and target in ALLOWED:
                    bad.append(f"{rel}: includes {inc}, but {own} may include only from {', '.join(ALLOWED[own]) or 'itself'}")
            if own == "engine/jobs" and rel not in YAML_LOADERS:
                for n, line in enumerate(f.read_text().splitlines(), 1):
                    if YAML_READ.search(line.split("//")[0]):
                        bad.append(f"{rel}:{n}: reads the recipe's YAML in a job; parse it at load into a typed "
                                   "struct (engine/recipe/) and read that")
    print("\n".join(bad) if bad else "layers: every #include points down")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
