"""Cheaper visual models of the arms: the same robot files with simplified visual meshes.

The tiny renderer spends its time on triangles, not pixels: the Kuka's 15k triangles take ~3.7 ms of a
~5 ms frame and the Gen3's ~90k triangles ~30 ms. Seen from the table camera one pixel covers 1.2–2 cm at the
arm, so merging the vertices that share a cell of a few millimetres (vertex clustering) removes most
triangles while the image hardly changes (`bench/env_speed.py` measures how many pixels differ).

Simplified copies are made once per machine under the data dir's cache; the robot description files are
copied with only their mesh references changed, so kinematics, inertia and colours stay the same.
"""

import contextlib
import hashlib
import os
import re
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from core.paths import data_subdir

LOWPOLY_VERSION = 1
DEFAULT_CELL_M = 0.004


def simplify(
    vertices: np.ndarray, faces: np.ndarray, cell_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertex clustering: vertices in the same `cell_m` cube merge into their mean; collapsed faces go.

    Returns (vertices, faces, cluster index of every input vertex).
    """
    keys = np.floor(vertices / cell_m).astype(np.int64)
    _, cluster, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    cluster = cluster.reshape(-1)
    merged = np.zeros((len(counts), 3))
    np.add.at(merged, cluster, vertices)
    merged /= counts[:, None]
    new_faces = cluster[faces]
    keep = (
        (new_faces[:, 0] != new_faces[:, 1])
        & (new_faces[:, 1] != new_faces[:, 2])
        & (new_faces[:, 0] != new_faces[:, 2])
    )
    new_faces = new_faces[keep]
    _, first = np.unique(np.sort(new_faces, axis=1), axis=0, return_index=True)
    return merged, new_faces[np.sort(first)], cluster


def read_stl(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Binary STL -> (unique vertices, faces)."""
    data = path.read_bytes()
    count = int(np.frombuffer(data, np.uint32, 1, 80)[0])
    records = np.frombuffer(data, np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]), count, 84)
    corners = records["v"].reshape(-1, 3).astype(np.float64)
    vertices, index = np.unique(corners, axis=0, return_inverse=True)
    return vertices, index.reshape(-1, 3)


def write_stl(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    triangles = vertices[faces].astype(np.float32)
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    records = np.zeros(len(faces), np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]))
    records["n"], records["v"] = normals, triangles
    path.write_bytes(b"varbot lowpoly".ljust(80, b" ") + np.uint32(len(faces)).tobytes() + records.tobytes())


def read_obj(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Triangle OBJ -> (vertices, faces, normals, face-corner normal indices)."""
    vertices, normals, faces, corner_normals = [], [], [], []
    for line in path.read_text().splitlines():
        if line.startswith("v "):
            vertices.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("vn "):
            normals.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("f "):
            corners = [corner.split("/") for corner in line.split()[1:4]]
            faces.append([int(c[0]) - 1 for c in corners])
            corner_normals.append([int(c[2]) - 1 if len(c) > 2 and c[2] else int(c[0]) - 1 for c in corners])
    return np.array(vertices), np.array(faces), np.array(normals), np.array(corner_normals)


def simplify_obj(source: Path, target: Path, cell_m: float) -> None:
    """Simplify a smooth-shaded OBJ; each merged vertex gets the mean of the normals that met there."""
    vertices, faces, normals, corner_normals = read_obj(source)
    merged, new_faces, cluster = simplify(vertices, faces, cell_m)
    summed = np.zeros_like(merged)
    np.add.at(summed, cluster[faces].reshape(-1), normals[corner_normals].reshape(-1, 3))
    summed /= np.maximum(np.linalg.norm(summed, axis=1, keepdims=True), 1e-12)
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in merged]
    lines += [f"vn {x:.5f} {y:.5f} {z:.5f}" for x, y, z in summed]
    lines += [f"f {a}//{a} {b}//{b} {c}//{c}" for a, b, c in new_faces + 1]
    target.write_text("\n".join(lines) + "\n")


def simplify_stl(source: Path, target: Path, cell_m: float) -> None:
    vertices, faces = read_stl(source)
    merged, new_faces, _ = simplify(vertices, faces, cell_m)
    write_stl(target, merged, new_faces)


MESH_REFERENCE = re.compile(r'(filename="|<uri>)([^"<]+)')
VISUAL_BLOCK = re.compile(r"<visual\b.*?</visual>", re.DOTALL)
SIMPLIFIERS: dict[str, Callable[[Path, Path, float], None]] = {".obj": simplify_obj, ".stl": simplify_stl}


def lowpoly_model(description: Path, cell_m: float = DEFAULT_CELL_M) -> Path:
    """A copy of the URDF/SDF `description` whose visual meshes are simplified (collision meshes untouched).

    Every other relative mesh path is made absolute, so the copy loads from the cache folder.
    """
    text = description.read_text()
    key = hashlib.sha1(f"{description.resolve()}|{text}|{cell_m}|{LOWPOLY_VERSION}".encode()).hexdigest()[:12]
    cache = data_subdir("cache", "lowpoly")
    folder = cache / f"{description.stem}-{key}"
    model = folder / description.name
    if model.exists():
        return model
    staging = Path(tempfile.mkdtemp(prefix=".staging-", dir=cache))
    try:

        def original(reference: str) -> Path:
            return (description.parent / reference.lstrip("/")).resolve()

        def simplified(match: re.Match) -> str:
            source = original(match.group(2))
            simplifier = SIMPLIFIERS.get(source.suffix.lower())
            if simplifier is None:
                return match.group(0)
            target = staging / f"{source.stem}.lowpoly{source.suffix.lower()}"
            if not target.exists():
                simplifier(source, target, cell_m)
            return match.group(1) + str(folder / target.name)

        def absolute(match: re.Match) -> str:
            reference = match.group(2)
            if reference.startswith(str(folder)) or not original(reference).exists():
                return match.group(0)
            return match.group(1) + str(original(reference))

        text = VISUAL_BLOCK.sub(lambda block: MESH_REFERENCE.sub(simplified, block.group(0)), text)
        (staging / description.name).write_text(MESH_REFERENCE.sub(absolute, text))
        with contextlib.suppress(OSError):  # another process may have won the race: its copy is as good
            os.replace(staging, folder)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return model
