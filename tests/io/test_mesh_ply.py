"""Binary triangle PLY meshes are read as fixed-length records, exactly as trimesh reads
them, and anything else (quads, ASCII) still goes through trimesh."""

from __future__ import annotations

import numpy as np
import trimesh

from treesim.cloud import LABEL_CODES
from treesim.io.mesh import load_mesh, write_mesh


def test_a_binary_triangle_ply_reads_as_trimesh_reads_it(tmp_path):
    m = trimesh.creation.icosphere(subdivisions=3)
    path = tmp_path / "leaves.ply"
    m.export(path)  # binary, no label property
    (part,) = load_mesh(path)
    ref = trimesh.load(path, process=False)
    np.testing.assert_array_equal(part.vertices, np.asarray(ref.vertices, dtype=np.float64))
    np.testing.assert_array_equal(part.faces, np.asarray(ref.faces))
    assert (part.name, part.label) == ("leaves.ply", "leaf")  # labelled from the file name


def test_labelled_ply_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(3)
    v = rng.normal(size=(50, 3)) * 1e3 + [5e5, 5.5e6, 300.0]  # float64 survives
    f = rng.integers(0, 50, size=(80, 3))
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    labels = rng.integers(1, 3, size=len(f)).astype(np.uint8)
    path = write_mesh(tmp_path / "m.ply", v, f, face_label=labels)
    parts = load_mesh(path)
    assert {p.label for p in parts} == {"wood", "leaf"}
    assert sum(len(p.faces) for p in parts) == len(f)
    for p in parts:
        code = LABEL_CODES[p.label]
        # every triangle, corner for corner, bit for bit (each part keeps its own vertices)
        np.testing.assert_array_equal(p.vertices[p.faces], v[f[labels == code]])


def test_quads_and_ascii_go_through_trimesh(tmp_path):
    quad = tmp_path / "quad.ply"
    quad.write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 4\n"
        b"property float x\nproperty float y\nproperty float z\n"
        b"element face 1\nproperty list uchar int vertex_indices\nend_header\n"
        + np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], "<f4").tobytes()
        + bytes([4])
        + np.array([0, 1, 2, 3], "<i4").tobytes()
    )
    (part,) = load_mesh(quad)
    assert len(part.faces) == 2  # the quad, triangulated
    m = trimesh.creation.box()
    m.export(tmp_path / "box.ply", encoding="ascii")
    (box,) = load_mesh(tmp_path / "box.ply")
    assert len(box.faces) == 12


def test_a_quad_after_triangles_is_not_read_as_a_triangle(tmp_path):
    # plyfile checks every list against the fixed length, not only the first
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0]], "<f4")
    body = v.tobytes()
    for face in ([0, 1, 4], [1, 2, 4], [0, 1, 2, 3]):
        body += bytes([len(face)]) + np.array(face, "<i4").tobytes()
    path = tmp_path / "mixed.ply"
    path.write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 5\n"
        b"property float x\nproperty float y\nproperty float z\n"
        b"element face 3\nproperty list uchar int vertex_indices\nend_header\n" + body
    )
    from treesim.io.mesh import _load_ply

    # the fixed-length read refuses it: trimesh gets the file (and triangulates)
    assert _load_ply(path, None) is None


def _plyfile_writes(path, v, f, lab):
    """The mesh as plyfile's own writer lays it out (the writer write_mesh used before it
    wrote the records as numpy buffers): the oracle for the bytes."""
    from plyfile import PlyData, PlyElement

    from treesim.cloud import LABEL_NAMES

    vert = np.empty(len(v), dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8")])
    vert["x"], vert["y"], vert["z"] = v[:, 0], v[:, 1], v[:, 2]
    face = np.empty(len(f), dtype=[("vertex_indices", "O"), ("label", "u1")])
    face["vertex_indices"] = list(f.astype(np.int32))
    face["label"] = lab
    names = ",".join(f"{k}={n}" for k, n in sorted(LABEL_NAMES.items()))
    PlyData(
        [
            PlyElement.describe(vert, "vertex"),
            PlyElement.describe(
                face, "face", len_types={"vertex_indices": "u1"}, val_types={"vertex_indices": "i4"}
            ),
        ],
        text=False,
        byte_order="<",
        comments=[f"treesim label_names {names}"],
    ).write(str(path))


def test_the_ply_writer_writes_plyfiles_bytes(tmp_path):
    rng = np.random.default_rng(7)
    for n_v, n_f in ((0, 0), (3, 1), (500, 997)):
        v = rng.normal(size=(n_v, 3)) * 10.0 + [3e5, 5e6, 120.0]
        f = rng.integers(0, max(n_v, 1), size=(n_f, 3))
        lab = rng.integers(0, 4, size=n_f).astype(np.uint8)
        ours = write_mesh(tmp_path / f"ours_{n_f}.ply", v, f, face_label=lab)
        theirs = tmp_path / f"theirs_{n_f}.ply"
        _plyfile_writes(theirs, v, f, lab)
        assert ours.read_bytes() == theirs.read_bytes(), (n_v, n_f)
