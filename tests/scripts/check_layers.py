#!/usr/bin/env python3
"""The build's layering rule, checked on every #include: a folder may include only from itself and
from the folders below it (docs/architecture.md). A new folder must be added here, with its place."""
import pathlib
import re
import sys

# folder -> the folders it may include from (besides itself). Lower layers first.
ALLOWED = {
    "fields": [],
    "mesher/extract": ["fields"],
    "mesher/slice": ["fields"],
    "mesher/writers": ["fields", "mesher/extract", "mesher/slice"],
    "engine/core": ["fields"],
    "engine/density": ["fields", "engine/core"],
    "engine/frames": ["fields", "engine/core"],
    "engine/parts": ["fields", "mesher/extract", "engine/core"],
    "engine/properties": ["fields", "engine/core"],  # to come: homogenization (issue 15)
    "engine/checks": ["fields", "mesher/extract", "mesher/slice", "engine/core"],  # pieces, printability
    "engine/recipe": ["fields", "mesher/extract", "engine/core", "engine/density", "engine/frames", "engine/parts"],
    "engine/jobs": ["fields", "mesher/extract", "mesher/slice", "mesher/writers", "engine/core", "engine/density",
                    "engine/frames", "engine/parts", "engine/properties", "engine/checks", "engine/recipe"],
}
INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.M)


def folder_of(path: str) -> str:
    parts = path.split("/")
    return parts[0] if parts[0] == "fields" else "/".join(parts[:2])


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
    print("\n".join(bad) if bad else "layers: every #include points down")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
