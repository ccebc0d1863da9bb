#!/usr/bin/env python3
"""Writes the seed corpus of every fuzz target to fuzz/corpus/<target>/: the
project's own files (db/, robot/, calib/) and small generated inputs (clouds,
meshes, FRI datagrams, puck frames, shared-memory messages, scene and grade files).
Run from anywhere: python3 fuzz/seed_corpus.py"""
import glob
import os
import shutil
import struct

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CORPUS = os.path.join(ROOT, "fuzz", "corpus")


def put(target, name, data):
    d = os.path.join(CORPUS, target)
    os.makedirs(d, exist_ok=True)
    if isinstance(data, str):
        data = data.encode()
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


def copy(target, pattern):
    for path in sorted(glob.glob(os.path.join(ROOT, pattern))):
        name = os.path.relpath(path, ROOT).replace("/", "_")
        with open(path, "rb") as f:
            put(target, name, f.read())


# Clouds: PCD ascii and binary (with normals), organised, plus issue 21's file.
pts = [(0.1, -0.2, 1.5), (float("nan"),) * 3, (0.3, 0.3, 0.3), (1, 2, 3)]
head = ("# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
        "WIDTH 2\nHEIGHT 2\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 4\n")
put("pcd", "ascii.pcd", head + "DATA ascii\n" + "".join("%r %r %r\n" % p for p in pts))
put("pcd", "binary.pcd", (head + "DATA binary\n").encode()
    + b"".join(struct.pack("<3f", *p) for p in pts))
put("pcd", "mixed.pcd", "VERSION 0.7\nFIELDS i x y z normal_x normal_y normal_z\nSIZE 2 8 4 4 4 4 4\n"
    "TYPE I F F F F F F\nCOUNT 1 1 1 1 1 1 1\nWIDTH 1\nHEIGHT 1\nDATA ascii\n-7 1 2 3 0 0 1\n")
put("pcd", "issue21.pcd", b"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 8\nTYPE F F F\n"
    b"COUNT 1 1 2305843009213693952\nWIDTH 2\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\n"
    b"DATA binary\n" + bytes(16))

# Meshes: a tetrahedron in every format.
V = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
F = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
put("obj", "tet.obj", "# tet\n" + "".join("v %g %g %g\n" % v for v in V)
    + "f 1/1/1 3//3 2\nf 1 2 4\nf -4 -1 -2\nf 2 3 4 2\n")
ply_head = ("ply\nformat %s 1.0\ncomment tet\nobj_info width 4\nelement vertex 4\nproperty float x\n"
            "property float y\nproperty float z\nelement face 4\n"
            "property list uchar int vertex_indices\nend_header\n")
put("ply", "tet_ascii.ply", ply_head % "ascii" + "".join("%g %g %g\n" % v for v in V)
    + "".join("3 %d %d %d\n" % f for f in F))
for fmt, e in (("binary_little_endian", "<"), ("binary_big_endian", ">")):
    put("ply", "tet_%s.ply" % fmt, (ply_head % fmt).encode()
        + b"".join(struct.pack(e + "3f", *v) for v in V)
        + b"".join(struct.pack(e + "B3i", 3, *f) for f in F))
smallest = min(glob.glob(os.path.join(ROOT, "db/*/models/*.ply")), key=os.path.getsize)
copy("ply", os.path.relpath(smallest, ROOT))
stl_ascii = "solid tet\n"
for f in F:
    stl_ascii += " facet normal 0 0 0\n  outer loop\n"
    stl_ascii += "".join("   vertex %g %g %g\n" % V[i] for i in f)
    stl_ascii += "  endloop\n endfacet\n"
put("stl", "tet_ascii.stl", stl_ascii + "endsolid tet\n")
put("stl", "tet_binary.stl", b"graspcell".ljust(80, b" ") + struct.pack("<I", len(F))
    + b"".join(struct.pack("<3f", 0, 0, 0) + b"".join(struct.pack("<3f", *V[i]) for i in f)
               + b"\0\0" for f in F))

# FRI: a measurement (916 bytes) and a command (376 bytes) with valid headers.
def fri(size, ident):
    return struct.pack("<4H", 7, 6, size, ident) + bytes(size - 8)
put("fri", "measurement.bin", fri(916, 0x2006))
put("fri", "command.bin", fri(376, 0x1005))

# Puck frames: 2 bytes of identifier, then the data.
for name, ident, data in [("get", 11, b"\x05"), ("set16", 11, b"\x80\x00\x34\x12"),
                          ("set32", 0x405, b"\x9e\x00\x01\x02\x03\x04"),
                          ("reply", 0x566, b"\x85\x00\x10\x00"),
                          ("position", 0x563, b"\x80\x12\x34"),
                          ("position6", 0x563, b"\x80\x12\x34\xbf\xff\xff")]:
    put("puck", name + ".bin", struct.pack("<H", ident) + data)

# Shared-memory messages: the first byte chooses the topic, then the message bytes.
ident = [1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0]
pose = struct.pack("<16d", *ident)
name = lambda s: s.encode().ljust(32, b"\0")
put("ipc", "request.bin", b"\0" + struct.pack("<2Q", 1, 2) + name("mug") + name("handle") + name("eq2"))
put("ipc", "cloud.bin", b"\1" + struct.pack("<2Q2I", 1, 2, 2, 1) + struct.pack("<4d", 525, 525, 319.5, 239.5)
    + struct.pack("<2I", 0, 0) + pose + struct.pack("<6f", 0, 0, 1, 0.1, 0, 1))
fit = struct.pack("<2I", 0, 0) + pose + struct.pack("<3d", 1e-6, 1e-6, 0.9)
put("ipc", "fits.bin", b"\2" + struct.pack("<2Q2I", 1, 2, 1, 0) + fit)
put("ipc", "plan.bin", b"\3" + struct.pack("<2Q", 1, 2) + pose + pose + bytes(8 * 14 + 8 + 8) + name("eq2"))
put("ipc", "joints.bin", b"\4" + struct.pack("<2Q", 1, 2) + struct.pack("<11d", *([0.1] * 11)) + struct.pack("<2I", 1, 0))
for topic in range(5, 10):
    put("ipc", "topic%d.bin" % topic, bytes([topic]) + bytes(200))

# Text files of the project.
copy("urdf", "robot/*.urdf")
copy("cell_toml", "robot/cell.toml")
copy("teach_toml", "db/*/grasps.toml")
copy("category_json", "db/*/category.json")
copy("calib_json", "calib/*.json")
put("scene_toml", "scene.toml", """base_from_camera = { xyz = [1.25, 0.0, 0.8], rpy = [-2.43, 0.0, 1.57] }
[table]
height_m = 0.0
center_xy_m = [0.65, 0.0]
extent_xy_m = [0.8, 1.2]
thickness_m = 0.05
[[objects]]
category = "mug"
seed = 3
pose = { xyz = [0.7, -0.1, 0.0] }
[[objects]]
mesh = "models/cup.obj"
scale = 0.001
pose = { xyz = [0.6, 0.1, 0.0], rpy = [0.0, 0.0, 1.0] }
""")
put("grade_csv", "grades.csv", '\ufefftrial_id,grade,cause,note\r\n1,success,,\r\n2,failure,registration,"a ""quoted""\nnote"\r\n3,,,\r\n')
put("grade_csv", "short.csv", "trial_id,grade\n1,partial\n")
print("seed corpus written to", CORPUS)
