"""AMASS motion on an SMPL-H body, for users who hold the AMASS and SMPL-H licences.

Nothing here ships or downloads data: the user supplies AMASS ``.npz`` motion files and an
SMPL-H model file (``.npz`` in the standard layout, e.g. AMASS's ``smplh/<gender>/model.npz``).
Tests write small synthetic files of their own in the same layout.

The SpecTrHuMS recipe: vertices from the body and hand pose and the subject's betas, with NO
root orientation (the first 3 pose values are zeroed) and NO translation; frames are taken with
stride ``floor(fps / 25)`` (30 fps for 60 or 120 Hz sources, 25 for 50 Hz), and each sequence
records its effective frame rate ``fps / stride``.

Skinning is our own small batched linear-blend-skinning routine (``SMPLH.forward``): shape
blend shapes, pose blend shapes (``R_j - I`` of every non-root joint), rigid transforms down the
kinematic tree, and skinning with the model's weights. The ``smplx`` package would do the same,
but its code is under a non-commercial licence (MPI), which this MIT project cannot depend on.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import torch

from zoo.core.io import progress_bar, sha256_file
from zoo.data.expmap import DataFormatError
from zoo.data.mesh import MeshDataset, MeshSequence, MeshTopology, recipe_hash
from zoo.data.skeleton import kinematic_chain, rodrigues

AMASS_KEYS = ("poses", "betas", "trans", "gender", "mocap_framerate")
MODEL_KEYS = ("v_template", "shapedirs", "posedirs", "J_regressor", "weights", "kintree_table", "f")
TARGET_FPS = 25.0
# The 22 body joints of SMPL/SMPL-H (root included): SpecTrHuMS regresses these from the mesh.
SMPLH_BODY_JOINTS = (
    "pelvis",
    "left_hip",
    "right_hip",
    "spine1",
    "left_knee",
    "right_knee",
    "spine2",
    "left_ankle",
    "right_ankle",
    "spine3",
    "left_foot",
    "right_foot",
    "neck",
    "left_collar",
    "right_collar",
    "head",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
)
DATASET_FORMAT = 1
SKIN_BATCH = 256


def frame_stride(fps: float, target_fps: float = TARGET_FPS) -> int:
    """``floor(fps / 25)`` (at least 1): the AMASS frame-rate policy of the literature (30 fps
    from 120 Hz and from 60 Hz sources; the effective fps is recorded per sequence)."""
    if not np.isfinite(fps) or fps <= 0:
        raise ValueError(f"frame rate must be positive, got {fps}")
    return max(1, int(math.floor(fps / target_fps + 1e-9)))


# ---- the body model --------------------------------------------------------------------------


def _load_npz(path: Path, what: str) -> dict[str, np.ndarray]:
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise DataFormatError(f"{path}: {what} file not found") from None
    except (ValueError, OSError) as e:
        raise DataFormatError(f"{path}: cannot read {what} as .npz ({e})") from e


def _check_shape(path: Path, key: str, array: np.ndarray, shape: tuple) -> None:
    """``shape`` entries: an int (exact) or None (any)."""
    ok = array.ndim == len(shape) and all(s is None or s == a for s, a in zip(shape, array.shape))
    if not ok:
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise DataFormatError(f"{path}: key {key!r} has shape {array.shape}, expected {want}")


@dataclass
class SMPLH:
    """An SMPL-H-layout body model: arrays as float64 tensors, ``parents[0] == -1``."""

    path: Path
    v_template: torch.Tensor  # (V, 3)
    shapedirs: torch.Tensor  # (V, 3, B)
    posedirs: torch.Tensor  # (V, 3, 9 (J - 1))
    j_regressor: torch.Tensor  # (J, V)
    weights: torch.Tensor  # (V, J)
    parents: tuple[int, ...]
    faces: np.ndarray  # (F, 3) int64
    sha256: str

    @property
    def num_vertices(self) -> int:
        return self.v_template.shape[0]

    @property
    def num_joints(self) -> int:
        return len(self.parents)

    @property
    def num_betas(self) -> int:
        return self.shapedirs.shape[2]

    def forward(
        self, poses: torch.Tensor, betas: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Vertices ``(T, V, 3)`` and joints ``(T, J, 3)`` (model units) of axis-angle
        ``poses (T, 3 J)`` for one body ``betas (n <= B,)``; no translation is applied."""
        dtype = self.v_template.dtype
        poses = torch.as_tensor(poses, dtype=dtype)
        betas = torch.as_tensor(betas, dtype=dtype)
        n_joints = self.num_joints
        if poses.ndim != 2 or poses.shape[1] != 3 * n_joints:
            raise ValueError(
                f"{self.path}: poses must be (T, {3 * n_joints}), got {tuple(poses.shape)}"
            )
        if betas.ndim != 1 or betas.shape[0] > self.num_betas:
            raise ValueError(
                f"{self.path}: betas must be (n <= {self.num_betas},), got {tuple(betas.shape)}"
            )
        t = poses.shape[0]
        v_shaped = self.v_template + self.shapedirs[..., : betas.shape[0]] @ betas  # (V, 3)
        joints = self.j_regressor @ v_shaped  # (J, 3)
        rot = rodrigues(poses.reshape(t, n_joints, 3), exact=True)  # (T, J, 3, 3)
        eye = torch.eye(3, dtype=dtype)
        pose_feature = (rot[:, 1:] - eye).reshape(t, -1)  # (T, 9 (J - 1))
        v_posed = v_shaped + torch.einsum("vcp,tp->tvc", self.posedirs, pose_feature)
        # Rigid transforms down the tree: G_j = G_parent [R_j | J_j - J_parent].
        parents = list(self.parents)
        is_root = torch.tensor([p < 0 for p in parents])
        offsets = joints - joints[[max(p, 0) for p in parents]].masked_fill(is_root[:, None], 0.0)
        g_rot, g_pos = kinematic_chain(parents, rot, offsets)  # (T, J, 3, 3), (T, J, 3)
        # Relative to the rest pose: x -> G_rot (x - J_j) + G_pos.
        rel_pos = g_pos - (g_rot @ joints[None, :, :, None])[..., 0]
        blend_rot = torch.einsum("vj,tjab->tvab", self.weights, g_rot)
        blend_pos = torch.einsum("vj,tja->tva", self.weights, rel_pos)
        vertices = (blend_rot @ v_posed[..., None])[..., 0] + blend_pos
        return vertices, g_pos


def _require_keys(path: Path, data, keys, what: str) -> None:
    for key in keys:
        if key not in data:
            raise DataFormatError(
                f"{path}: {what} has no key {key!r} (expected keys {', '.join(keys)})"
            )


def load_smplh(path: str | Path) -> SMPLH:
    """Read and check an SMPL-H model ``.npz`` (keys ``MODEL_KEYS``, standard shapes)."""
    path = Path(path)
    data = _load_npz(path, "SMPL-H model")
    _require_keys(path, data, MODEL_KEYS, "SMPL-H model")
    v = data["v_template"]
    _check_shape(path, "v_template", v, (None, 3))
    n_v = v.shape[0]
    kintree = data["kintree_table"]
    _check_shape(path, "kintree_table", kintree, (2, None))
    n_j = kintree.shape[1]
    _check_shape(path, "shapedirs", data["shapedirs"], (n_v, 3, None))
    _check_shape(path, "posedirs", data["posedirs"], (n_v, 3, 9 * (n_j - 1)))
    _check_shape(path, "J_regressor", data["J_regressor"], (n_j, n_v))
    _check_shape(path, "weights", data["weights"], (n_v, n_j))
    _check_shape(path, "f", data["f"], (None, 3))
    for key in ("v_template", "shapedirs", "posedirs", "J_regressor", "weights"):
        if not np.issubdtype(data[key].dtype, np.floating) or not np.isfinite(data[key]).all():
            raise DataFormatError(
                f"{path}: key {key!r} must hold finite floats, got {data[key].dtype}"
            )
    if not np.array_equal(kintree[1].astype(np.int64), np.arange(n_j)):
        raise DataFormatError(
            f"{path}: kintree_table row 1 must list the joints 0..{n_j - 1} in order"
        )
    parents_raw = kintree[0].astype(np.int64)
    parents = [-1] + [int(p) for p in parents_raw[1:]]
    for j, p in enumerate(parents[1:], start=1):
        if not 0 <= p < j:
            raise DataFormatError(
                f"{path}: kintree_table gives joint {j} the parent {p}; "
                f"parents must come before their children"
            )
    faces = data["f"]
    if not np.issubdtype(faces.dtype, np.integer) or faces.min() < 0 or faces.max() >= n_v:
        raise DataFormatError(f"{path}: key 'f' must hold vertex indices in [0, {n_v})")
    weight_sums = data["weights"].sum(axis=1)
    if np.abs(weight_sums - 1).max() > 1e-4:
        raise DataFormatError(
            f"{path}: skinning weights of vertex "
            f"{int(np.argmax(np.abs(weight_sums - 1)))} sum to "
            f"{weight_sums[np.argmax(np.abs(weight_sums - 1))]:.6f}, not 1"
        )

    def t(key):
        return torch.as_tensor(np.asarray(data[key], dtype=np.float64))

    return SMPLH(
        path=path,
        v_template=t("v_template"),
        shapedirs=t("shapedirs"),
        posedirs=t("posedirs"),
        j_regressor=t("J_regressor"),
        weights=t("weights"),
        parents=tuple(parents),
        faces=np.asarray(faces, dtype=np.int64),
        sha256=sha256_file(path),
    )


# ---- AMASS motion ----------------------------------------------------------------------------


@dataclass
class AmassMotion:
    path: Path
    poses: np.ndarray  # (T, 3 J) axis-angle
    betas: np.ndarray  # (B,)
    trans: np.ndarray  # (T, 3)
    gender: str
    fps: float


def read_amass(path: str | Path, num_joints: int | None = None) -> AmassMotion:
    """Read an AMASS ``.npz`` (keys ``AMASS_KEYS``); a missing key or a wrong shape is an error
    naming the file and the key. ``num_joints`` checks ``poses`` has ``3 * num_joints`` columns."""
    path = Path(path)
    data = _load_npz(path, "AMASS motion")
    _require_keys(path, data, AMASS_KEYS, "AMASS file")
    poses = data["poses"]
    _check_shape(path, "poses", poses, (None, None if num_joints is None else 3 * num_joints))
    if poses.shape[1] % 3:
        raise DataFormatError(f"{path}: key 'poses' has {poses.shape[1]} columns, not 3 per joint")
    if len(poses) == 0:
        raise DataFormatError(f"{path}: key 'poses' holds no frames")
    betas = data["betas"]
    _check_shape(path, "betas", betas, (None,))
    _check_shape(path, "trans", data["trans"], (len(poses), 3))
    gender = data["gender"]
    if gender.ndim != 0 or gender.dtype.kind not in "US":
        raise DataFormatError(
            f"{path}: key 'gender' must be a string, got {gender.dtype} {gender.shape}"
        )
    gender = gender.item()
    gender = gender.decode() if isinstance(gender, bytes) else str(gender)
    rate = data["mocap_framerate"]
    if rate.size != 1 or not np.issubdtype(rate.dtype, np.number):
        raise DataFormatError(
            f"{path}: key 'mocap_framerate' must be one number, got {rate.dtype} {rate.shape}"
        )
    fps = float(rate.reshape(()))
    if not np.isfinite(fps) or fps <= 0:
        raise DataFormatError(f"{path}: key 'mocap_framerate' must be positive, got {fps}")
    for key, arr in (("poses", poses), ("betas", betas), ("trans", data["trans"])):
        if not np.issubdtype(arr.dtype, np.number) or not np.isfinite(arr).all():
            raise DataFormatError(f"{path}: key {key!r} must hold finite numbers")
    return AmassMotion(
        path=path,
        poses=poses.astype(np.float64),
        betas=betas.astype(np.float64),
        trans=data["trans"].astype(np.float64),
        gender=gender.strip().lower(),
        fps=fps,
    )


def amass_vertices(
    model: SMPLH, motion: AmassMotion, *, batch_size: int = SKIN_BATCH
) -> tuple[np.ndarray, int]:
    """The SpecTrHuMS mesh sequence of ``motion``: vertices ``(T', V, 3)`` in mm (float32) at
    stride ``frame_stride(fps)``, root orientation zeroed, no translation; and the stride."""
    if motion.poses.shape[1] != 3 * model.num_joints:
        raise DataFormatError(
            f"{motion.path}: key 'poses' has {motion.poses.shape[1]} columns; "
            f"the model {model.path.name} has {model.num_joints} joints "
            f"({3 * model.num_joints} columns)"
        )
    stride = frame_stride(motion.fps)
    poses = motion.poses[::stride].copy()
    poses[:, :3] = 0.0  # no root orientation
    n_betas = min(len(motion.betas), model.num_betas)
    betas = torch.as_tensor(motion.betas[:n_betas])
    chunks = []
    with torch.no_grad():
        for start in range(0, len(poses), batch_size):
            v, _ = model.forward(torch.as_tensor(poses[start : start + batch_size]), betas)
            chunks.append((v * 1000.0).float().numpy())
    return np.concatenate(chunks), stride


# ---- the dataset builder ---------------------------------------------------------------------


def amass_files(root: str | Path) -> list[Path]:
    """Every motion ``.npz`` under ``root`` (AMASS's per-subject ``shape.npz`` left out)."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: AMASS folder not found")
    files = sorted(p for p in root.rglob("*.npz") if p.name != "shape.npz")
    if not files:
        raise DataFormatError(f"{root}: no AMASS .npz motion files found")
    return files


def build_amass(
    root: str | Path,
    model: str | Path | Mapping[str, str | Path],
    *,
    split: str,
    name: str = "amass",
    files: Iterable[str | Path] | None = None,
    cache_dir: str | Path | None = None,
    progress: bool = True,
) -> MeshDataset:
    """AMASS motion files on SMPL-H as a ``MeshDataset`` (SpecTrHuMS recipe, mm).

    - ``root``: a folder of AMASS ``.npz`` files (e.g. one sub-dataset such as BMLrub);
      ``files`` (paths relative to ``root`` or absolute) restricts the selection;
    - ``model``: one SMPL-H model file for every sequence, or a mapping ``gender -> file``
      used by each file's ``gender`` (the joint regressor then comes from ``"neutral"`` if
      given, else from the first gender in sorted order);
    - ``split``: the label of the result (AMASS splits are by sub-dataset: pass the files).

    Each sequence's ``action`` is the first folder under ``root`` (the sub-dataset), or
    ``name``; ``meta`` records file, sha256, gender, source fps, stride and effective fps. The
    joint regressor is the model's first 22 rows (the body joints, root included). Cached in
    ``<cache>/datasets/<name>-<split>-<recipe_hash>`` like the other mesh datasets.
    """

    from zoo.data.mesh import cache_root

    root = Path(root)
    paths = (
        amass_files(root)
        if files is None
        else [Path(f) if Path(f).is_absolute() else root / f for f in files]
    )
    loaded, reg_gender, regressor = _smplh_models(model)
    recipe = {
        "builder": "zoo.data.amass.build_amass",
        "format": DATASET_FORMAT,
        "source": "amass",
        "split": split,
        "recipe": "SpecTrHuMS: body + hand pose, subject betas, no root "
        "orientation, no translation",
        "frame_policy": "stride floor(fps / 25)",
        "units": "mm",
        "dtype": "float32",
        "models": {g: m.sha256 for g, m in sorted(loaded.items())},
        "regressor": {"model": reg_gender, "joints": len(SMPLH_BODY_JOINTS)},
        "files": [{"file": _relative(p, root), "sha256": sha256_file(p)} for p in paths],
    }
    key = recipe_hash(recipe)
    folder = cache_root(cache_dir) / "datasets" / f"{name}-{split}-{key}"
    if (folder / "dataset.json").is_file() and (folder / "meshes.npz").is_file():
        cached = MeshDataset.load(folder)
        if cached.recipe_hash == key:
            return cached
    first = next(iter(loaded.values()))
    topology = MeshTopology(first.faces, first.num_vertices, name=f"{name}-smplh")
    bar = progress_bar(paths, desc=f"{name}-{split}", unit="file", disable=not progress)
    sequences = [
        _amass_sequence(path, entry, loaded, name) for path, entry in zip(bar, recipe["files"])
    ]
    dataset = MeshDataset(
        name=f"{name}-{split}",
        split=split,
        topology=topology,
        sequences=sequences,
        recipe=recipe,
        joint_regressor=regressor,
        joint_names=list(SMPLH_BODY_JOINTS),
    )
    dataset.save(folder)
    return dataset


def _body_identity(motion: AmassMotion, body: SMPLH) -> str:
    """Sequences of one subject (same gender and betas) share an identity."""
    n = min(len(motion.betas), body.num_betas)
    digest = hashlib.sha256(np.ascontiguousarray(motion.betas[:n], dtype="<f8").tobytes())
    return f"{motion.gender}-{digest.hexdigest()[:12]}"


def _relative(path: Path, root: Path) -> str:
    try:
        return str(path.resolve().relative_to(root.resolve()))
    except ValueError:
        return str(path)


def _smplh_models(
    model: str | Path | Mapping[str, str | Path],
) -> tuple[dict[str, SMPLH], str, sp.csr_matrix]:
    """``build_amass``'s bodies by gender (``"any"`` for one file), the gender whose joint
    regressor the dataset carries, and that regressor's body rows."""
    models = (
        {"any": Path(model)}
        if isinstance(model, (str, Path))
        else {str(k).lower(): Path(v) for k, v in model.items()}
    )
    if not models:
        raise ValueError("model: no SMPL-H model file given")
    loaded = {g: load_smplh(p) for g, p in models.items()}
    faces = {m.faces.tobytes() for m in loaded.values()}
    if len(faces) != 1 or len({m.num_vertices for m in loaded.values()}) != 1:
        raise DataFormatError(
            f"model: the SMPL-H files {[str(p) for p in models.values()]} do "
            f"not share one triangulation"
        )
    reg_gender = (
        "any" if "any" in loaded else ("neutral" if "neutral" in loaded else sorted(loaded)[0])
    )
    reg_model = loaded[reg_gender]
    if reg_model.num_joints < len(SMPLH_BODY_JOINTS):
        raise DataFormatError(
            f"{reg_model.path}: {reg_model.num_joints} joints, fewer than the "
            f"{len(SMPLH_BODY_JOINTS)} SMPL body joints"
        )
    regressor = sp.csr_matrix(reg_model.j_regressor[: len(SMPLH_BODY_JOINTS)].numpy())
    return loaded, reg_gender, regressor


def _amass_sequence(
    path: Path, entry: dict[str, str], loaded: dict[str, SMPLH], name: str
) -> MeshSequence:
    """One AMASS file posed on its gender's body (``entry``: its recipe record)."""
    first = next(iter(loaded.values()))
    motion = read_amass(path, first.num_joints)
    body = loaded.get("any") or loaded.get(motion.gender)
    if body is None:
        raise DataFormatError(
            f"{path}: gender {motion.gender!r} has no model (given: {', '.join(sorted(loaded))})"
        )
    vertices, stride = amass_vertices(body, motion)
    rel = entry["file"]
    parts = Path(rel).parts
    return MeshSequence(
        name=rel,
        action=parts[0] if len(parts) > 1 else name,
        vertices=vertices,
        fps=motion.fps / stride,
        identity=_body_identity(motion, body),
        meta={
            "file": rel,
            "sha256": entry["sha256"],
            "gender": motion.gender,
            "source_fps": motion.fps,
            "stride": stride,
            "effective_fps": motion.fps / stride,
            "source_frames": len(motion.poses),
            "betas_used": int(min(len(motion.betas), body.num_betas)),
        },
    )
