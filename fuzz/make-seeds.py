#!/usr/bin/env python3
"""Seed corpora for the fuzz targets (fuzz/*_fuzz.cc): small valid inputs of every format.

    fuzz/make-seeds.py OUT_DIR [--sope BUILD/app/sope]

writes OUT_DIR/<target>/<seed>. The text and binary formats are generated here (the
shapes of the test data: a tetrahedron and a cube as meshes and clouds, in every encoding
the readers take); the database seed is a real database built by `sope build-db` from one
procedural object with 12 views (--sope), cut into the section form database_fuzz.cc reads.
Nothing is copied from ../shared/data.
"""
import argparse
import os
import shutil
import struct
import subprocess
import sys
import tempfile

TETRA_V = [(0.0, 0.0, 0.0), (0.1, 0.0, 0.0), (0.0, 0.1, 0.0), (0.0, 0.0, 0.1)]
TETRA_F = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
CUBE_V = [(x * 0.05, y * 0.05, z * 0.05) for x in (0, 1) for y in (0, 1) for z in (0, 1)]
CUBE_Q = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]


def write(directory, name, data):
    os.makedirs(directory, exist_ok=True)
    with open(os.path.join(directory, name), "wb") as f:
        f.write(data.encode() if isinstance(data, str) else data)


# ---- PLY ---------------------------------------------------------------------------------

def ply(fmt, vertices, faces=(), colours=False, normals=False, double=False):
    kind = "double" if double else "float"
    head = ["ply", f"format {fmt} 1.0", "comment sope fuzz seed",
            f"element vertex {len(vertices)}",
            f"property {kind} x", f"property {kind} y", f"property {kind} z"]
    if normals:
        head += ["property float nx", "property float ny", "property float nz"]
    if colours:
        head += ["property uchar red", "property uchar green", "property uchar blue"]
    if faces:
        head += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
    head.append("end_header")
    text = "\n".join(head) + "\n"
    if fmt == "ascii":
        body = ""
        for i, v in enumerate(vertices):
            items = [repr(c) for c in v]
            if normals:
                items += ["0", "0", "1"]
            if colours:
                items += [str(40 * i % 256), "128", "255"]
            body += " ".join(items) + "\n"
        for f in faces:
            body += f"{len(f)} " + " ".join(map(str, f)) + "\n"
        return (text + body).encode()
    e = "<" if fmt == "binary_little_endian" else ">"
    body = b""
    for i, v in enumerate(vertices):
        body += struct.pack(e + ("ddd" if double else "fff"), *v)
        if normals:
            body += struct.pack(e + "fff", 0.0, 0.0, 1.0)
        if colours:
            body += struct.pack("BBB", 40 * i % 256, 128, 255)
    for f in faces:
        body += struct.pack(e + "B" + "i" * len(f), len(f), *f)
    return text.encode() + body


def ply_seeds(out):
    d = os.path.join(out, "ply_fuzz")
    for fmt in ("ascii", "binary_little_endian", "binary_big_endian"):
        write(d, f"tetra_{fmt}.ply", ply(fmt, TETRA_V, TETRA_F))
        write(d, f"cloud_{fmt}.ply", ply(fmt, CUBE_V, colours=True, normals=True))
        write(d, f"cube_quads_{fmt}_double.ply", ply(fmt, CUBE_V, CUBE_Q, double=True))


# ---- PCD ---------------------------------------------------------------------------------

def pcd(encoding, points, rgb=False, normals=False):
    fields, sizes, types, counts = ["x", "y", "z"], ["4"] * 3, ["F"] * 3, ["1"] * 3
    if normals:
        fields += ["normal_x", "normal_y", "normal_z"]
        sizes += ["4"] * 3; types += ["F"] * 3; counts += ["1"] * 3
    if rgb:
        fields.append("rgb"); sizes.append("4"); types.append("F"); counts.append("1")
    n = len(points)
    head = (f"# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS {' '.join(fields)}\n"
            f"SIZE {' '.join(sizes)}\nTYPE {' '.join(types)}\nCOUNT {' '.join(counts)}\n"
            f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {encoding}\n")
    def values(i, p):
        v = list(p)
        if normals:
            v += [0.0, 0.0, 1.0]
        if rgb:
            v.append(struct.unpack("<f", struct.pack("<I", (40 * i % 256) << 16 | 128 << 8 | 255))[0])
        return v
    if encoding == "ascii":
        return (head + "".join(" ".join(repr(x) for x in values(i, p)) + "\n"
                               for i, p in enumerate(points))).encode()
    if encoding == "binary":
        return head.encode() + b"".join(struct.pack("<" + "f" * len(fields), *values(i, p))
                                        for i, p in enumerate(points))
    # binary_compressed: fields stored one after another (structure of arrays), then LZF;
    # this LZF stream holds literal runs only (control byte < 32: the next ctrl+1 bytes).
    columns = [[values(i, p)[k] for i, p in enumerate(points)] for k in range(len(fields))]
    raw = b"".join(struct.pack("<" + "f" * n, *c) for c in columns)
    lzf = b""
    for start in range(0, len(raw), 32):
        chunk = raw[start:start + 32]
        lzf += bytes([len(chunk) - 1]) + chunk
    return head.encode() + struct.pack("<II", len(lzf), len(raw)) + lzf


def pcd_seeds(out):
    d = os.path.join(out, "pcd_fuzz")
    for encoding in ("ascii", "binary", "binary_compressed"):
        write(d, f"tetra_{encoding}.pcd", pcd(encoding, TETRA_V))
        write(d, f"cube_rgb_normals_{encoding}.pcd", pcd(encoding, CUBE_V, rgb=True, normals=True))


# ---- OBJ / OFF / STL (mesh_fuzz: first byte picks the extension) ----------------------------

def obj(vertices, faces):
    text = "# sope fuzz seed\no tetra\n" + "".join(f"v {x} {y} {z}\n" for x, y, z in vertices)
    text += "vn 0 0 1\nvt 0 0\n"
    return text + "".join("f " + " ".join(f"{i + 1}/1/1" for i in f) + "\n" for f in faces)


def off(vertices, faces):
    text = f"OFF\n# sope fuzz seed\n{len(vertices)} {len(faces)} 0\n"
    text += "".join(f"{x} {y} {z}\n" for x, y, z in vertices)
    return text + "".join(f"{len(f)} " + " ".join(map(str, f)) + "\n" for f in faces)


def triangles(vertices, faces):
    for f in faces:
        for k in range(1, len(f) - 1):
            yield vertices[f[0]], vertices[f[k]], vertices[f[k + 1]]


def stl_ascii(vertices, faces):
    text = "solid seed\n"
    for a, b, c in triangles(vertices, faces):
        text += "  facet normal 0 0 1\n    outer loop\n"
        text += "".join(f"      vertex {x} {y} {z}\n" for x, y, z in (a, b, c))
        text += "    endloop\n  endfacet\n"
    return text + "endsolid seed\n"


def stl_binary(vertices, faces):
    tris = list(triangles(vertices, faces))
    data = b"sope fuzz seed".ljust(80, b" ") + struct.pack("<I", len(tris))
    for a, b, c in tris:
        data += struct.pack("<12fH", 0, 0, 1, *a, *b, *c, 0)
    return data


def mesh_seeds(out):
    d = os.path.join(out, "mesh_fuzz")
    write(d, "tetra.obj", b"o" + obj(TETRA_V, TETRA_F).encode())
    write(d, "cube_quads.OBJ", b"O" + obj(CUBE_V, CUBE_Q).encode())
    write(d, "tetra.off", b"f" + off(TETRA_V, TETRA_F).encode())
    write(d, "cube_quads.off", b"f" + off(CUBE_V, CUBE_Q).encode())
    write(d, "tetra_ascii.stl", b"s" + stl_ascii(TETRA_V, TETRA_F).encode())
    write(d, "cube_binary.stl", b"s" + stl_binary(CUBE_V, CUBE_Q))


# ---- frames.json, calibration YAML, CLI values -------------------------------------------------

def frames_json(axes, code, width, height, inverses, calibration):
    import json
    frames = [{"file": "white.png", "role": "white"}, {"file": "black.png", "role": "black"}]
    for axis in axes:
        size = width if axis == "x" else height
        bits = max(1, (size - 1).bit_length())
        for bit in range(bits - 1, -1, -1):
            for inverted in ((False, True) if inverses else (False,)):
                frames.append({"file": f"{axis}_{bit:02d}{'_inv' if inverted else ''}.png",
                               "role": "code", "axis": axis, "code": code, "bits": bits,
                               "bit": bit, "inverted": inverted})
    root = {"format": "sope-frames/1", "camera": {"width": 320, "height": 240},
            "projector": {"width": width, "height": height}, "frames": frames}
    if calibration:
        root["calibration"] = "calibration.yaml"
    return json.dumps(root, indent=2) + "\n"


def frames_seeds(out):
    d = os.path.join(out, "frames_json_fuzz")
    write(d, "xy_gray_inverses.json", frames_json("xy", "gray", 256, 192, True, True))
    write(d, "x_binary.json", frames_json("x", "binary", 100, 1, False, False))
    write(d, "y_gray.json", frames_json("y", "gray", 64, 48, False, True))


def matrix(name, rows, cols, values):
    data = ", ".join(repr(float(v)) for v in values)
    return f"{name}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {data} ]\n"


def calibration_yaml(distortion_terms):
    text = "%YAML:1.0\n---\n"
    text += "camera_width: 320\ncamera_height: 240\n"
    text += matrix("camera_matrix", 3, 3, [400, 0, 160, 0, 400, 120, 0, 0, 1])
    text += matrix("camera_distortion", 1, distortion_terms, [0.01, -0.02] + [0] * (distortion_terms - 2))
    text += "projector_width: 256\nprojector_height: 192\n"
    text += matrix("projector_matrix", 3, 3, [350, 0, 128, 0, 350, 96, 0, 0, 1])
    text += matrix("projector_distortion", 1, 5, [0] * 5)
    text += matrix("proj_from_cam_rotation", 3, 3,
                   [0.9689, 0, 0.2474, 0, 1, 0, -0.2474, 0, 0.9689])
    text += matrix("proj_from_cam_translation", 3, 1, [-0.15, 0, 0.02])
    text += "rms_camera_px: 0.25\nrms_projector_px: 0.4\nrms_stereo_px: 0.3\n"
    return text


def calibration_seeds(out):
    d = os.path.join(out, "calibration_yaml_fuzz")
    write(d, "rig_5.yaml", calibration_yaml(5))
    write(d, "rig_8.yaml", calibration_yaml(8))


def cli_seeds(out):
    d = os.path.join(out, "cli_numbers_fuzz")
    # first byte % 5: 0 ParseSize, 1 ParseNumbers, 2 ParseMeshUnit, 3 ParseLengthUnit,
    # 4 ParsePose
    for i, text in enumerate(["\x001024x768", "\x0032768X1", "\x010.5,1e-3,-2,7",
                              "\x0142", "\x02auto", "\x02mm", "\x030.0254", "\x03cm",
                              "\x0420,30,0,0,0,0.6", "\x04-90,0,180,0.1,-0.2,1e0"]):
        write(d, f"value_{i}", text)


# ---- database ----------------------------------------------------------------------------

def database_seeds(out, sope):
    d = os.path.join(out, "database_fuzz")
    with tempfile.TemporaryDirectory() as tmp:
        models = os.path.join(tmp, "models")
        subprocess.run([sope, "objects", "--instances", "1", "--out", models, "-q"], check=True)
        # one class is enough for a valid file
        classes = sorted(os.listdir(models))
        for extra in classes[1:]:
            shutil.rmtree(os.path.join(models, extra))
        db = os.path.join(tmp, "seed.sopedb")
        subprocess.run([sope, "build-db", "--models", models, "--views", "12", "--bits", "16",
                        "--threads", "1", "--out", db, "-q"], check=True)
        data = open(db, "rb").read()
    count = struct.unpack_from("<I", data, 16)[0]
    sections = b""
    for s in range(count):
        offset, size = struct.unpack_from("<QQ", data, 64 + 40 * s + 16)
        sections += struct.pack("<I", size) + data[offset:offset + size]
    write(d, "sections.bin", sections)  # laid out again by the target
    write(d, "header_and_table.sopedb", data[:64 + 40 * count])  # raw path (signature)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("out")
    parser.add_argument("--sope", help="the sope program, for the database seed")
    args = parser.parse_args()
    ply_seeds(args.out)
    pcd_seeds(args.out)
    mesh_seeds(args.out)
    frames_seeds(args.out)
    calibration_seeds(args.out)
    cli_seeds(args.out)
    if args.sope:
        database_seeds(args.out, args.sope)
    else:
        print("make-seeds: no --sope, database_fuzz gets no seed", file=sys.stderr)


if __name__ == "__main__":
    main()
