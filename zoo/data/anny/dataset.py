"""The CMU-on-Anny mesh datasets (``cmu_anny_*``): CMU BVH trials retargeted onto the Anny body
and skinned at 25 Hz, carrying the topology's joint regressor, with the rig's exact bone heads
beside them in the cache; their recipe, names and cache folders, and the benchmark loader.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np

from zoo.core.errors import DataNotFoundError
from zoo.core.io import atomic_path, progress_bar, sha256_file
from zoo.data.anny.body import (
    DEFAULT_PHENOTYPE,
    MI_PHENOTYPE_RANGES,
    TOPOLOGIES,
    TRIANGULATION,
    anny_version,
    bvh_joint_order,
    mi_phenotype,
    model_faces,
    one_thread,
    shared_model,
)
from zoo.data.anny.regressor import JointRegressor, joint_regressor
from zoo.data.anny.retargeting import (
    ROOT_MODES,
    TARGET_FPS,
    motion_rotations,
    retarget,
    skin,
    snapped_fps,
)
from zoo.data.anny.trials import SPLIT_RULE, Trial, select_trials
from zoo.data.bvh import CMU_BVH_JOINTS, read_bvh
from zoo.data.mesh import MeshDataset, MeshSequence, MeshTopology, cache_root, recipe_hash

IDENTITY_MODES = ("one", "many")
DATASET_FORMAT = 1
# Identifiers recorded in every format-1 recipe: names, not documentation (the mapping is
# described in docs/datasets.md); changing one re-keys every cmu_anny dataset and results row.
BUILDER_ID = "zoo.data.anny_motion.build_cmu_anny"
MAPPING_ID = (
    "SPEC section 7: Z-Y-X local rotations, M (x,y,z)->(x,-z,y), rest "
    "correction C per bone, pose [[C_parent^T R' C, 0], [0, 1]]"
)


# How each sequence's vertices were computed (its meta): the bytes, not the recipe, so not in the
# protocol; a cache built otherwise (float32 skinning, before) is rebuilt.
SKINNING = "float64, rounded once to float32"


def dataset_name(identities: str, topology: str, split: str, root: str = "identity") -> str:
    tag = {"one": "oi", "many": "mi"}[identities]
    suffix = "" if root == "identity" else "-noheading"
    return f"cmu_anny-{tag}-{topology}{suffix}-{split}"


def dataset_folder(dataset: MeshDataset, cache_dir: str | Path | None = None) -> Path:
    """Where ``build_cmu_anny`` keeps ``dataset``: ``<cache>/datasets/<name>-<recipe_hash>``."""
    return _folder(dataset.name, dataset.recipe_hash, cache_dir)


def _folder(name: str, key: str, cache_dir: str | Path | None) -> Path:
    return cache_root(cache_dir) / "datasets" / f"{name}-{key}"


def dataset_recipe(
    trials: Sequence[Trial],
    regressor: JointRegressor,
    *,
    identities: str,
    topology: str,
    split: str,
    root: str = "identity",
    seed: int = 0,
) -> dict[str, Any]:
    """What a CMU-on-Anny dataset of ``trials`` is built from (format ``DATASET_FORMAT``): its
    hash names the cache folder and enters the protocol ids of every result scored on it, so
    a value here changes only with the data it describes."""
    return {
        "builder": BUILDER_ID,
        "format": DATASET_FORMAT,
        "source": "cmu_bvh",
        "identities": identities,
        "topology": topology,
        "anny_topology": TOPOLOGIES[topology],
        # Only where the zoo triangulates: the low recipe (and its cache key) stays as it was.
        **({"triangulation": TRIANGULATION[topology]} if topology in TRIANGULATION else {}),
        "rig": "cmu_mb",
        "split": split,
        "split_rule": SPLIT_RULE,
        "root": root,
        # The seed only draws MI bodies: OI datasets of any seed are one dataset.
        "seed": int(seed) if identities == "many" else None,
        "anny_version": anny_version(),
        "fps": TARGET_FPS,
        "resampling": "drop frame 0 (T-pose); slerp of local rotations to 25 Hz",
        "mapping": MAPPING_ID,
        "units": "mm",
        "dtype": "float32",
        "threads": 1,
        "phenotypes": (
            DEFAULT_PHENOTYPE
            if identities == "one"
            else {"ranges": MI_PHENOTYPE_RANGES, "draw": "mi_phenotype(seed, trial)"}
        ),
        "trials": [{"trial": t.key, "sha256": sha256_file(t.path)} for t in trials],
        "joint_regressor": regressor.recipe,
    }


def _check_arguments(identities: str, topology: str, root: str, seed: Any) -> None:
    if identities not in IDENTITY_MODES:
        raise ValueError(f"identities must be one of {IDENTITY_MODES}, got {identities!r}")
    if topology not in TOPOLOGIES:
        raise ValueError(f"topology must be one of {sorted(TOPOLOGIES)}, got {topology!r}")
    if root not in ROOT_MODES:
        raise ValueError(f"root must be one of {ROOT_MODES}, got {root!r}")
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool):
        raise ValueError(f"seed must be an integer, got {seed!r}")


def _load_cached(folder: Path, key: str, regressor: JointRegressor) -> MeshDataset | None:
    """The dataset cached in ``folder`` for the recipe hashed ``key``, carrying ``regressor``;
    None if none."""
    if not ((folder / "dataset.json").is_file() and (folder / "meshes.npz").is_file()):
        return None
    cached = MeshDataset.load(folder)
    if cached.recipe_hash != key or any(
        s.meta.get("skinning") != SKINNING for s in cached.sequences
    ):
        return None
    # A dataset cached before its regressor shipped carries this machine's fit.
    if cached.joint_regressor is None or (abs(cached.joint_regressor - regressor.matrix) > 0).nnz:
        cached.joint_regressor = regressor.matrix
    return cached


def _skin_trials(
    model,
    trials: Sequence[Trial],
    entries: Sequence[dict[str, Any]],
    *,
    identities: str,
    seed: int,
    root: str,
    progress: bool,
    desc: str,
) -> tuple[list[MeshSequence], list[np.ndarray]]:
    """Each trial retargeted and skinned on its body (``entries``: the recipe's record of each
    trial): the mesh sequences and the rig's posed bone heads ``(T, 31, 3)`` (mm, BVH joint
    order) of each."""
    to_bvh = bvh_joint_order(model)
    sequences, rig_joints = [], []
    bar = progress_bar(trials, desc=desc, unit="trial", disable=not progress)
    frames_done = 0
    for trial, entry in zip(bar, entries):
        bvh = read_bvh(trial.path, CMU_BVH_JOINTS)
        rots = motion_rotations(bvh)
        pheno = DEFAULT_PHENOTYPE if identities == "one" else mi_phenotype(seed, trial.key)
        with one_thread():
            target = retarget(model, bvh, pheno)
            out = skin(model, target.pose_parameters(rots, root), pheno, return_bone_ends=True)
        frames_done += len(rots)
        bar.set_postfix(frames=frames_done)
        sequences.append(
            MeshSequence(
                name=trial.key,
                action=trial.description,
                vertices=out["vertices"],
                fps=TARGET_FPS,
                identity="default" if identities == "one" else f"mi{seed}-{trial.key}",
                meta={
                    "trial": trial.key,
                    "bvh": trial.relpath,
                    "sha256": entry["sha256"],
                    "subject": trial.subject,
                    "source_frames": bvh.num_frames - 1,
                    "source_fps": snapped_fps(bvh.frame_time),
                    "phenotype": dict(pheno),
                    "root": root,
                    "skinning": SKINNING,
                },
            )
        )
        rig_joints.append(out["heads"][:, to_bvh].astype(np.float32))
    return sequences, rig_joints


def build_cmu_anny(
    bvh_root: str | Path,
    *,
    identities: Literal["one", "many"],
    topology: Literal["full", "low"],
    split: Literal["train", "test"],
    seed: int = 0,
    cache_dir: str | Path | None = None,
    trials: Iterable[str] | None = None,
    progress: bool = True,
    root: Literal["identity", "no_heading"] = "identity",
) -> MeshDataset:
    """CMU BVH trials on the Anny body as a ``MeshDataset`` (vertices in mm, 25 Hz).

    - ``identities``: ``"one"`` (OI: Anny's default phenotype, every parameter 0.5) or
      ``"many"`` (MI: gender, age, muscle, weight, height, proportions drawn per sequence from
      ``MI_PHENOTYPE_RANGES`` by ``mi_phenotype(seed, trial)``);
    - ``topology``: ``"full"`` (13,718 vertices) or ``"low"`` (``notoes_collapse10pc``, 1,229);
    - ``split``: ``SPLIT_RULE``; ``trials`` (keys like ``"09_03"``) builds only those;
    - ``root``: ``"identity"`` (no global rotation: the motion-prediction protocol) or
      ``"no_heading"`` (heading removed, body tilt kept); root translation is always zero.

    Each sequence's ``action`` is the trial's MANIFEST description (or its subject); ``meta``
    records trial, file, sha256, source frames and fps and the phenotype. The dataset carries
    the topology's ``joint_regressor`` (BVH joint order). The result is cached in
    ``<cache>/datasets/<name>-<recipe_hash>`` (``cache_dir``, ``$ZOO_CACHE_DIR`` or
    ``<repo>/cache``), with the rig's exact per-frame bone heads beside it
    (``load_rig_joints``); a second call with the same recipe loads it.
    """
    _check_arguments(identities, topology, root, seed)
    chosen = select_trials(bvh_root, split, trials)
    regressor = joint_regressor(bvh_root, topology, cache_dir=cache_dir)
    recipe = dataset_recipe(
        chosen,
        regressor,
        identities=identities,
        topology=topology,
        split=split,
        root=root,
        seed=seed,
    )
    name = dataset_name(identities, topology, split, root)
    key = recipe_hash(recipe)
    folder = _folder(name, key, cache_dir)
    cached = _load_cached(folder, key, regressor)
    if cached is not None:
        return cached
    model = shared_model(topology)
    topo = MeshTopology(
        model_faces(model), model.template_vertices.shape[0], name=f"anny-{TOPOLOGIES[topology]}"
    )
    sequences, rig_joints = _skin_trials(
        model,
        chosen,
        recipe["trials"],
        identities=identities,
        seed=seed,
        root=root,
        progress=progress,
        desc=name,
    )
    dataset = MeshDataset(
        name=name,
        split=split,
        topology=topo,
        sequences=sequences,
        recipe=recipe,
        joint_regressor=regressor.matrix,
        joint_names=list(CMU_BVH_JOINTS),
    )
    with atomic_path(folder / "rig_joints.npz") as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **{f"seq{i}": j for i, j in enumerate(rig_joints)})
    dataset.save(folder)
    return dataset


def load_rig_joints(folder: str | Path) -> list[np.ndarray]:
    """The rig's posed bone heads ``(T, 31, 3)`` (mm, BVH joint order) per sequence of a
    dataset folder written by ``build_cmu_anny`` (``dataset_folder(dataset)``)."""
    path = Path(folder) / "rig_joints.npz"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no rig joints (build the dataset with build_cmu_anny)")
    with np.load(path) as z:
        return [z[f"seq{i}"] for i in range(len(z.files))]


def cmu_anny_dataset(
    root: str | Path | None, split: str, *, identities: str, topology: str
) -> MeshDataset:
    """A benchmark loader (field ``loader`` of ``benchmarks/*.yaml``): ``root`` is the CMU BVH
    folder
    (the benchmark's ``data_root``); built on first use, then loaded from the cache."""
    if root is None:
        raise DataNotFoundError(
            "no CMU BVH folder given: pass --data-root pointing at the folder "
            "holding MANIFEST.tsv and data/ (../shared/data/cmu_bvh here)"
        )
    return build_cmu_anny(root, identities=identities, topology=topology, split=split)
