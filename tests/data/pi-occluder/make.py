#!/usr/bin/env python3
"""Writes the Π-shaped occluder of tests/data/pi-occluder/ (issue 47, item 4).

Two legs and a top bar of 28 unit voxel cubes (1.5 cm), in the frame of
config/photos/saunders-chair.toml, written twice:

- voxels.obj: every cube's 12 triangles, each cube with its own 8 vertices,
  so each face two cubes share appears twice (336 triangles), as a voxel
  editor's STL export has it;
- boxes.obj: the same solid as 3 boxes (each leg, the bar), 36 triangles.

Every coordinate is x0 + i h for an integer i, computed the same way in both
files, so the two meshes hold the same points to the last bit.
Run from this folder: python3 make.py
"""

H = 0.015
X0, Y0, Z0 = 0.49, 0.60, 0.08


def corner(i, j, k):
    return (X0 + i * H, Y0 + j * H, Z0 + k * H)


def box(lo, hi):
    """The 12 triangles of the box from integer corner lo to hi, outward CCW."""
    (a, b, c), (d, e, f) = lo, hi
    v = [corner(x, y, z) for z in (c, f) for y in (b, e) for x in (a, d)]
    # v index = x + 2 y + 4 z with x, y, z in {0, 1}
    quads = [
        (0, 2, 3, 1),  # z low
        (4, 5, 7, 6),  # z high
        (0, 1, 5, 4),  # y low
        (2, 6, 7, 3),  # y high
        (0, 4, 6, 2),  # x low
        (1, 3, 7, 5),  # x high
    ]
    return v, [(q[0], q[1], q[2]) for q in quads] + [(q[0], q[2], q[3]) for q in quads]


def cubes():
    out = [(0, 0, k) for k in range(11)] + [(5, 0, k) for k in range(11)]
    out += [(i, 0, 11) for i in range(6)]
    assert len(out) == 28
    return out


def write(path, boxes, comment):
    lines = [f"# {comment}", "# Written by make.py; see its docstring."]
    faces = []
    n = 0
    for lo, hi in boxes:
        v, tris = box(lo, hi)
        lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in v]
        faces += [f"f {n + a + 1} {n + b + 1} {n + c + 1}" for a, b, c in tris]
        n += len(v)
    with open(path, "w") as f:
        f.write("\n".join(lines + faces) + "\n")


write(
    "voxels.obj",
    [((i, j, k), (i + 1, j + 1, k + 1)) for i, j, k in cubes()],
    "A Π of 28 voxel cubes, every cube's 12 triangles (internal faces twice).",
)
write(
    "boxes.obj",
    [((0, 0, 0), (1, 1, 11)), ((5, 0, 0), (6, 1, 11)), ((0, 0, 11), (6, 1, 12))],
    "The same Π as 3 boxes: two legs and the bar.",
)
