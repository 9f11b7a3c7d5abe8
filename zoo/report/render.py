"""Ground truth and prediction side by side, as pictures and as meshes.

For a mesh benchmark, ``render_windows`` draws a few test windows: one row per window pair
(ground truth above, prediction below), one column per chosen horizon, each mesh shaded by its
per-vertex error; the same frames are exported as ``.glb`` scenes a viewer can open.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from zoo.core.io import atomic_path
from zoo.data.catalog import mesh_windows
from zoo.data.mesh import MeshDataset
from zoo.evaluation.evaluator import predict
from zoo.protocol.plan import check_task


def predicted_windows(
    model,
    bench,
    dataset: MeshDataset,
    windows: Sequence[int],
    task: str = "prediction",
    horizon: int | None = None,
):
    """Ground truth ``(W, T_in + T, V, 3)`` and prediction ``(W, T, V, 3)`` of chosen windows."""
    t_in = bench.input_frames
    t_out = check_task(task, horizon, bench.output_frames)
    truth, rows = mesh_windows(dataset, bench, windows, t_out)
    with torch.no_grad():
        history = torch.from_numpy(truth[:, :t_in])
        pred = predict(model.eval(), history, task, t_out, torch.from_numpy(truth[:, -1]))
    return truth, pred.numpy(), rows


def render_windows(
    model,
    model_name: str,
    bench,
    dataset: MeshDataset,
    windows: Sequence[int],
    out_dir: str | Path,
    horizons_ms: Sequence[int] = (80, 400, 1000),
    task: str = "prediction",
    horizon: int | None = None,
) -> list[Path]:
    """Write ``<model>_windows.png`` and one ``<model>_window<i>.glb`` per window."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import trimesh
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    truth, pred, index = predicted_windows(model, bench, dataset, windows, task, horizon)
    t_in = bench.input_frames
    frame_ms = 1000.0 / dataset.fps
    columns = [
        int(round(h / frame_ms)) - 1
        for h in horizons_ms
        if 0 < round(h / frame_ms) <= pred.shape[1]
    ]
    faces = dataset.topology.faces
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    # Views: the dataset's vertical axis up. Body meshes here are y-up after export, cloth z-up.
    fig = plt.figure(figsize=(3.0 * (len(columns) + 1), 3.0 * 2 * len(windows)))
    for row, w in enumerate(windows):
        scale = 0.6 * np.ptp(truth[row].reshape(-1, 3), axis=0).max()  # zoom on this window
        seq = dataset.sequences[index[row, 0]]
        panels = [("observed", truth[row, t_in - 1], None)]
        for c in columns:
            err = np.linalg.norm(pred[row, c] - truth[row, t_in + c], axis=-1)
            panels.append((f"{(c + 1) * frame_ms:.0f} ms", truth[row, t_in + c], None))
            panels.append((f"{(c + 1) * frame_ms:.0f} ms", pred[row, c], err))
        centre = truth[row, t_in - 1].mean(axis=0)
        for i, (title, verts, err) in enumerate(panels):
            r = 2 * row + (1 if err is not None else 0)
            col = 0 if i == 0 else 1 + (i - 1) // 2
            ax = fig.add_subplot(
                2 * len(windows),
                len(columns) + 1,
                r * (len(columns) + 1) + col + 1,
                projection="3d",
            )
            tris = verts[faces]
            if err is None:
                colours = np.full((len(faces), 4), (0.62, 0.62, 0.65, 1.0))
            else:
                face_err = err[faces].mean(axis=1)
                colours = plt.cm.inferno(np.clip(face_err / max(scale * 0.2, 1e-9), 0, 1))
            ax.add_collection3d(Poly3DCollection(tris, facecolors=colours, linewidths=0))
            for axis, setter in enumerate((ax.set_xlim, ax.set_ylim, ax.set_zlim)):
                setter(centre[axis] - scale, centre[axis] + scale)
            ax.set_axis_off()
            label = "ground truth" if err is None else f"{model_name} (mean {err.mean():.1f} mm)"
            ax.set_title(
                f"{title}\n{label}" if i else f"window {w}: {seq.name}\n{title}", fontsize=7
            )
    fig.suptitle(
        f"{bench.name}: {model_name}, ground truth (grey) vs prediction (coloured by vertex error)",
        fontsize=9,
    )
    fig.tight_layout()
    written = [out_dir / f"{model_name}_windows.png"]
    with atomic_path(written[0]) as tmp:
        fig.savefig(tmp, format="png", dpi=90)
    plt.close(fig)
    for row, w in enumerate(windows):
        scene = trimesh.Scene()
        extent = float(np.ptp(truth[row, ..., 0])) / 1000.0 * 1.3
        for j, c in enumerate(columns):
            for k, (verts, colour) in enumerate(
                ((truth[row, t_in + c], (150, 150, 150, 255)), (pred[row, c], (220, 90, 40, 255)))
            ):
                mesh = trimesh.Trimesh(
                    verts / 1000.0 + [j * extent, k * extent, 0], faces, process=False
                )
                mesh.visual.face_colors = colour
                scene.add_geometry(mesh, node_name=f"{'truth' if k == 0 else 'pred'}_{c + 1:03d}")
        path = out_dir / f"{model_name}_window{w}.glb"
        with atomic_path(path) as tmp:
            tmp.write_bytes(scene.export(file_type="glb"))
        written.append(path)
    return written
