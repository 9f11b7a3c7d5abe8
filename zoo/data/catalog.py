"""What ``zoo data`` says about a dataset, and exporting a window of a mesh dataset to look at."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from zoo.data.mesh import MeshDataset, MeshError
from zoo.data.motion import MotionDataset
from zoo.data.windows import check_sampler, gather_windows, window_sampler

EXPORT_FORMATS = (".glb", ".ply")


def describe(dataset: MeshDataset | MotionDataset) -> dict[str, Any]:
    """Sizes, frame rate, identities and hashes of a dataset, as ordered (field, value) pairs."""
    frames = sum(len(s) for s in dataset.sequences)
    info: dict[str, Any] = {
        "dataset": dataset.name,
        "split": dataset.split,
        "sequences": len(dataset.sequences),
        "frames": frames,
        "actions": len({s.action for s in dataset.sequences}),
    }
    if isinstance(dataset, MeshDataset):
        topology = dataset.topology
        info.update(
            {
                "fps": dataset.fps,
                "duration_s": round(frames / dataset.fps, 1),
                "vertices": topology.num_vertices,
                "faces": len(topology.faces),
                "edges": len(topology.edges),
                "identities": len({s.identity for s in dataset.sequences}),
                "joint_regressor": (
                    f"{dataset.joint_regressor.shape[0]} joints"
                    if dataset.joint_regressor is not None
                    else "none"
                ),
                "size_mb": round(sum(s.vertices.nbytes for s in dataset.sequences) / 2**20, 1),
                "topology_hash": topology.hash,
                "recipe_hash": dataset.recipe_hash,
                "content_hash": dataset.content_hash(),
            }
        )
    else:
        info.update(
            {
                "fps": dataset.fps,
                "skeleton": dataset.skeleton.name,
                "joints": dataset.skeleton.num_joints,
                "root": str(dataset.root),
                "files_sha256": ", ".join(
                    f"{f['file']}={f['sha256'][:12]}" for f in dataset.files()[:3]
                )
                + (" ..." if len(dataset.sequences) > 3 else ""),
            }
        )
        if dataset.notes:
            info["notes"] = "; ".join(dataset.notes)
    return info


def mesh_windows(
    dataset: MeshDataset,
    bench,
    windows,
    output_frames: int,
    sampler: str | None = None,
    option: str = "--windows",
):
    """Windows number ``windows`` of the benchmark's sampler: vertices ``(W, T_in + T_out, V, 3)``
    and their ``(sequence, start)`` rows; an index out of range names ``option``."""
    sampler = check_sampler(sampler or bench.sampler)
    t_in = bench.input_frames
    index = window_sampler(sampler, [len(s) for s in dataset.sequences], t_in, output_frames)
    bad = [w for w in windows if not 0 <= w < len(index)]
    if bad:
        shown = bad[0] if option == "--window" else bad
        raise MeshError(
            f"{option} {shown}: {dataset.name}/{dataset.split} has {len(index)} "
            f"windows under sampler {sampler} (valid: 0..{len(index) - 1})"
        )
    rows = index[list(windows)]
    return gather_windows([s.vertices for s in dataset.sequences], rows, t_in + output_frames), rows


def export_window(
    dataset: MeshDataset, bench, window: int, out: str | Path, sampler: str | None = None
) -> list[Path]:
    """Write window ``window`` of the benchmark's sampler through trimesh: a ``.glb`` scene with
    the frames side by side (observed in grey, future in blue), or one ``.ply`` per frame."""
    import trimesh

    from zoo.core.io import atomic_path

    if not isinstance(dataset, MeshDataset):
        raise MeshError(f"{dataset.name} is a skeleton dataset: only mesh windows export")
    out = Path(out)
    if out.suffix not in EXPORT_FORMATS:
        raise MeshError(f"--out {out}: expected a file ending in {' or '.join(EXPORT_FORMATS)}")
    t_in = bench.input_frames
    frames = (
        mesh_windows(dataset, bench, [window], bench.output_frames, sampler, option="--window")[0][
            0
        ]
        / 1000.0
    )  # mm -> m, the unit viewers expect
    faces = dataset.topology.faces
    extent = float(np.ptp(frames[..., 0]))
    written = []
    if out.suffix == ".glb":
        scene = trimesh.Scene()
        for t, vertices in enumerate(frames):
            mesh = trimesh.Trimesh(vertices + [t * 1.2 * extent, 0, 0], faces, process=False)
            mesh.visual.face_colors = [150, 150, 150, 255] if t < t_in else [60, 110, 220, 255]
            scene.add_geometry(mesh, node_name=f"frame_{t:03d}")
        with atomic_path(out) as tmp:
            tmp.write_bytes(scene.export(file_type="glb"))
        written.append(out)
    else:
        for t, vertices in enumerate(frames):
            path = out.with_name(f"{out.stem}_{t:03d}.ply")
            with atomic_path(path) as tmp:
                tmp.write_bytes(
                    trimesh.Trimesh(vertices, faces, process=False).export(file_type="ply")
                )
            written.append(path)
    return written
