#!/bin/bash
# Runs every libFuzzer harness for a fixed budget (FUZZ_SECONDS each, default 60) from a seed
# corpus built out of data/ (recipes, meshes, wireframes, cells, value files). Findings (crash-*,
# timeout-*, oom-*) land in BUILD/fuzz-findings/; the script fails if any harness found one.
# Usage: run_fuzz.sh SOURCE_DIR BUILD_DIR
set -u
src=$1
build=$2
seconds=${FUZZ_SECONDS:-60}
corpus=$build/fuzz-corpus
findings=$build/fuzz-findings
mkdir -p "$findings"

# Seeds: the shipped files, with the format-picking first byte the harnesses read.
seed() {  # seed HARNESS PREFIX-BYTE FILE...
    local harness=$1 byte=$2
    shift 2
    mkdir -p "$corpus/$harness"
    for f in "$@"; do
        [ -f "$f" ] || continue
        if [ -n "$byte" ]; then
            { printf "\\x$byte"; head -c 200000 "$f"; } >"$corpus/$harness/$(basename "$f")"
        else
            head -c 200000 "$f" >"$corpus/$harness/$(basename "$f")"
        fi
    done
}
seed recipe "" "$src"/data/recipes/*.yaml
grep -ho '"[^"]*"' "$src"/data/recipes/*.yaml | tr -d '"' | head -200 | while read -r eq; do
    mkdir -p "$corpus/equation"
    printf '%s' "$eq" >"$corpus/equation/$(printf '%s' "$eq" | md5sum | cut -c1-12)"
done
# Small hand-written seeds for the formats data/ does not ship.
tiny=$build/fuzz-tiny
mkdir -p "$tiny"
printf 'ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nelement face 4\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n' >"$tiny/tet.ply"
printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n' >"$tiny/tet.obj"
printf 'v 0 0 0\nv 1 1 1\nv 1 0 0\nl 1 2\nl 2 3\n' >"$tiny/cell.obj"
printf '0,0,0,1,1,1,0.2,0.2\n1,1,1,2,0,1,0.2,0.3\n' >"$tiny/frame.csv"
printf '0.1,0.2,0.3\n0.4,0.5,0.6\n' >"$tiny/values.csv"
seed mesh 00 "$src"/data/meshes/*.stl
seed mesh 01 "$tiny/tet.ply"
seed mesh 02 "$tiny/tet.obj"
# A 3MF tetrahedron (zip, content types, relationships, model), for the reader behind libzip.
/usr/bin/python3 - "$tiny/tet.3mf" <<'PY'
import sys, zipfile
model = ('<?xml version="1.0" encoding="UTF-8"?><model unit="millimeter" xml:lang="en-US" '
         'xmlns="http://schemas.microsoft.com/3dmanufacturing/core/2015/02"><resources><object id="1" '
         'type="model"><mesh><vertices><vertex x="0" y="0" z="0"/><vertex x="1" y="0" z="0"/><vertex x="0" '
         'y="1" z="0"/><vertex x="0" y="0" z="1"/></vertices><triangles><triangle v1="0" v2="2" v3="1"/>'
         '<triangle v1="0" v2="1" v3="3"/><triangle v1="0" v2="3" v3="2"/><triangle v1="1" v2="2" v3="3"/>'
         '</triangles></mesh></object></resources><build><item objectid="1"/></build></model>')
with zipfile.ZipFile(sys.argv[1], "w", zipfile.ZIP_DEFLATED) as z:
    z.writestr("[Content_Types].xml", '<?xml version="1.0" encoding="UTF-8"?><Types xmlns="http://schemas.'
               'openxmlformats.org/package/2006/content-types"><Default Extension="rels" ContentType="application/'
               'vnd.openxmlformats-package.relationships+xml"/><Default Extension="model" ContentType="application/'
               'vnd.ms-package.3dmanufacturing-3dmodel+xml"/></Types>')
    z.writestr("_rels/.rels", '<?xml version="1.0" encoding="UTF-8"?><Relationships xmlns="http://schemas.'
               'openxmlformats.org/package/2006/relationships"><Relationship Target="/3D/3dmodel.model" Id="rel0" '
               'Type="http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"/></Relationships>')
    z.writestr("3D/3dmodel.model", model)
PY
seed mesh 03 "$tiny/tet.3mf"
seed wireframe 01 "$src"/data/recipes/*.csv "$tiny/frame.csv"
seed wireframe 00 "$tiny/cell.obj"
seed values 00 "$tiny/values.csv"
seed values 01 "$tiny/cell.obj"
seed profile "" "$src"/data/printers/*.yaml
printf 'material: form2\nproperties: {resolution: 8}\n' >"$tiny/properties.yaml"
printf 'material: {E: 1.6 GPa, nu: 0.38, k: 0.2}\nproperties: {cell: [4, 4, 4], resolution: 6, tolerance: 1e-4}\n' >"$tiny/properties2.yaml"
seed properties "" "$tiny/properties.yaml" "$tiny/properties2.yaml"

# Leaks inside third-party libraries only (lib3mf's libzip error record), as in `make sanitize`.
export LSAN_OPTIONS=suppressions=$src/tests/lsan.supp
# oneTBB's sentinel cast only (tests/ubsan.supp); every other report stops the harness.
export UBSAN_OPTIONS=suppressions=$src/tests/ubsan.supp:halt_on_error=1:print_stacktrace=1
status=0
for harness in recipe equation mesh wireframe values profile properties; do
    mkdir -p "$corpus/$harness" "$findings/$harness"
    echo "fuzzing $harness for ${seconds} s"
    if ! "$build/fuzz_$harness" -max_total_time="$seconds" -timeout=10 -rss_limit_mb=4096 -max_len=65536 \
        -artifact_prefix="$findings/$harness/" "$corpus/$harness" >"$findings/$harness.log" 2>&1; then
        echo "fuzz_$harness found a defect: see $findings/$harness/ and $findings/$harness.log"
        tail -30 "$findings/$harness.log"
        status=1
    else
        grep -E "^(Done|#[0-9]+ +DONE)" "$findings/$harness.log" | tail -1
    fi
done
exit $status
