"""A folder of real photos as a data set with the paper's pseudo ground truth (``data=folder``).

``FolderFaces(root)`` takes every JPEG/PNG under ``root`` (any size), runs the pseudo-GT
pipeline of :mod:`disent.data.photos.pseudo_gt` once (cached by content hash) and serves items with
the same keys as :class:`disent.data.SynthFaces` where they exist: ``image``,
``normal_pseudo``, ``mask_pseudo``, ``uv_pseudo``, ``normal_uv_pseudo``, ``sh_pseudo``, and
``attrs`` when the folder has attribute labels.  Real photos have no ground truth, so none of
the GT keys (``albedo``, ``shading``, ``normal``, ...) are present.

A CelebA download is recognised by its layout::

    root/img_align_celeba/000001.jpg ...
    root/list_attr_celeba.txt        # 40 attributes, +1/-1; feeds attrs and the editing pools
    root/list_eval_partition.txt     # optional: 0 train, 1 val, 2 test

Without a partition file the split of a photo is fixed by a hash of its relative path and
``seed`` (80/10/10), so adding photos never moves the others.
"""

from __future__ import annotations

import hashlib
import logging
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from disent.data.attributes import ATTRIBUTES
from disent.data.photos.pseudo_gt import (
    IMAGE_SUFFIXES,
    PseudoGTSettings,
    crop_pixels,
    format_summary,
    load_cached,
    prepare,
)

log = logging.getLogger(__name__)

# CelebA column -> (our attribute, sign): beard is "not No_Beard", senior is "not Young".
CELEBA_COLUMNS = {
    "smiling": ("Smiling", 1),
    "beard": ("No_Beard", -1),
    "eyeglasses": ("Eyeglasses", 1),
    "senior": ("Young", -1),
}
SPLIT_FRACTIONS = {"train": 0.8, "val": 0.1, "test": 0.1}
SPLIT_BY = ("hash", "all")  # all: train, val and test are each the whole folder (a handful of photos)
PSEUDO_KEYS = ("normal_pseudo", "mask_pseudo", "uv_pseudo", "normal_uv_pseudo")


def list_images(root: Path) -> list[Path]:
    """Image files under ``root`` (``img_align_celeba/`` only, when that folder exists), sorted."""
    base = root / "img_align_celeba" if (root / "img_align_celeba").is_dir() else root
    return sorted(
        p
        for p in base.rglob("*")
        if p.suffix.lower() in IMAGE_SUFFIXES
        and (p.is_file() or p.is_symlink())
        and not any(part.startswith(".") for part in p.relative_to(base).parts)
    )


def read_celeba_attributes(path: Path) -> dict[str, dict[str, float]]:
    """``list_attr_celeba.txt`` -> {file name: {smiling, beard, eyeglasses, senior: 0./1.}}."""
    lines = path.read_text().splitlines()
    names = lines[1].split()
    cols = {ours: (names.index(col), sign) for ours, (col, sign) in CELEBA_COLUMNS.items()}
    out = {}
    for line in lines[2:]:
        parts = line.split()
        if len(parts) != len(names) + 1:
            continue
        vals = parts[1:]
        out[parts[0]] = {ours: float(int(vals[i]) * sign > 0) for ours, (i, sign) in cols.items()}
    return out


def read_partition(path: Path) -> dict[str, str]:
    names = {"0": "train", "1": "val", "2": "test"}
    return {f: names[s] for f, s in (line.split() for line in path.read_text().splitlines() if line.strip())}


def hash_split(relpath: str, seed: int) -> str:
    u = int(hashlib.sha1(f"{seed}:{relpath}".encode()).hexdigest()[:8], 16) / 2**32
    return "train" if u < SPLIT_FRACTIONS["train"] else "val" if u < 1 - SPLIT_FRACTIONS["test"] else "test"


class FolderFaces(Dataset):
    """Real photos with pseudo ground truth; see the module docstring.

    ``split``: ``train``, ``val``, ``test``, or ``pool_<attr>`` (the test split's photos,
    balanced: even items positive for ``<attr>``, odd negative, as in SynthFaces; needs labels).
    ``size`` keeps the first ``size`` usable photos of the split.  The remaining arguments are
    :class:`~disent.data.photos.pseudo_gt.PseudoGTSettings` fields and the pipeline's cache, workers
    and (for tests) a ``detector`` replacing dlib.
    """

    def __init__(
        self,
        root,
        split: str = "train",
        resolution: int = 64,
        seed: int = 0,
        size: int | None = None,
        cache_dir=None,
        workers: int = 0,
        progress: bool = True,
        detector=None,
        split_by: str = "hash",
        **pseudo_gt,
    ):
        self.root = Path(root).expanduser()
        if not self.root.is_dir():
            raise FileNotFoundError(f"FolderFaces: {self.root} is not a folder")
        if split_by not in SPLIT_BY:
            raise ValueError(f"FolderFaces: split_by={split_by!r}; choose from {', '.join(SPLIT_BY)}")
        self.split, self.resolution, self.seed, self.split_by = split, resolution, seed, split_by
        self.settings = PseudoGTSettings(resolution=resolution, **pseudo_gt)
        attr_file = self.root / "list_attr_celeba.txt"
        self.attributes = read_celeba_attributes(attr_file) if attr_file.is_file() else None
        files = self._split_files(split)
        self.records, self.summary = self._prepare(files, size, cache_dir, workers, progress, detector)
        if split.startswith("pool_"):  # as SynthFaces' pools: even items positive, odd negative
            attr = split[len("pool_") :]
            label = lambda r: self.attributes[Path(r.path).name][attr] > 0  # noqa: E731
            pos, neg = [r for r in self.records if label(r)], [r for r in self.records if not label(r)]
            self.records = [r for pair in zip(pos, neg) for r in pair][:size]
        if not self.records:
            raise ValueError(
                f"FolderFaces: no usable face among {len(files)} images of split {split!r} "
                f"in {self.root}\n{format_summary(self.summary)}"
            )

    # -- which files
    def _split_files(self, split: str) -> list[Path]:
        files = list_images(self.root)
        if not files:
            raise FileNotFoundError(f"FolderFaces: no {'/'.join(IMAGE_SUFFIXES)} files under {self.root}")
        base = files[0].parent if (self.root / "img_align_celeba").is_dir() else self.root
        part_file = self.root / "list_eval_partition.txt"
        partition = read_partition(part_file) if part_file.is_file() else None

        def split_of(p: Path) -> str:
            rel = p.relative_to(base).as_posix()
            return partition.get(rel, hash_split(rel, self.seed)) if partition else hash_split(rel, self.seed)

        if self.attributes is not None:  # every item then carries attrs, so batches collate
            unlabeled = [p for p in files if p.name not in self.attributes]
            if unlabeled:
                log.warning("FolderFaces: %d images have no attribute labels and are left out", len(unlabeled))
            files = [p for p in files if p.name in self.attributes]
        if split in SPLIT_FRACTIONS:
            return files if self.split_by == "all" else [p for p in files if split_of(p) == split]
        if split.startswith("pool_"):
            attr = split[len("pool_") :]
            if attr not in ATTRIBUTES:
                raise ValueError(
                    f"FolderFaces: unknown attribute pool {split!r}; have {[f'pool_{a}' for a in ATTRIBUTES]}"
                )
            if self.attributes is None:
                raise ValueError(
                    f"FolderFaces: split {split!r} needs attribute labels "
                    f"({self.root / 'list_attr_celeba.txt'} is missing)"
                )
            test = [p for p in files if split_of(p) == "test"]
            pos = [p for p in test if self.attributes[p.name][attr] > 0]
            neg = [p for p in test if self.attributes[p.name][attr] == 0]
            rng = np.random.default_rng(self.seed)
            pos, neg = ([ps[i] for i in rng.permutation(len(ps))] for ps in (pos, neg))
            return [p for pair in zip(pos, neg) for p in pair]  # positive, negative, positive, ...
        raise ValueError(
            f"FolderFaces: unknown split {split!r}; use train, val, test or pool_<attr> "
            f"(real photos have no light bank)"
        )

    def _prepare(self, files, size, cache_dir, workers, progress, detector):
        """Pseudo-GT for the split's files (only as many as ``size`` needs), keeping the used ones."""
        records, start = [], 0
        chunk = len(files) if size is None else max(2 * size, 64)
        all_recs = []
        while start < len(files) and (size is None or len(records) < size):
            recs, _ = prepare(
                files[start : start + chunk], self.settings, cache_dir, workers, progress, detector, log_summary=False
            )
            all_recs += recs
            records += [r for r in recs if r.used]
            start += chunk
        from disent.data.photos.pseudo_gt import summarize

        summary = summarize(all_recs)
        log.info("FolderFaces(%s, %s): %s", self.root, self.split, format_summary(summary))
        return records[:size] if size is not None else records, summary

    # -- items
    def __len__(self) -> int:
        return len(self.records)

    def __getitem__(self, index: int) -> dict:
        rec = self.records[index]
        z = load_cached(rec)
        f32 = lambda a: torch.from_numpy(np.asarray(a, dtype=np.float32))  # noqa: E731
        item = {"image": torch.from_numpy(crop_pixels(z["image"]))}  # linear radiance, as SynthFaces
        item.update({k: f32(z[k]) for k in PSEUDO_KEYS})
        item["sh_pseudo"] = f32(z["sh_pseudo"])
        if self.attributes is not None:
            labels = self.attributes[Path(rec.path).name]
            item["attrs"] = {a: torch.tensor(v) for a, v in labels.items()}
            item["attrs"].update({f"{a}_strength": torch.tensor(v) for a, v in labels.items()})
        return item


def build(cfg, split: str = "train", size: int | None = None) -> FolderFaces:
    """A :class:`FolderFaces` from a ``conf/data/folder.yaml`` node."""
    keys = {f.name for f in PseudoGTSettings.__dataclass_fields__.values()} - {"resolution"}
    extra = {k: cfg[k] for k in keys if k in cfg and cfg[k] is not None}
    return FolderFaces(
        cfg["root"],
        split=split,
        resolution=cfg["resolution"],
        seed=cfg.get("seed", 0),
        size=size,
        cache_dir=cfg.get("cache_dir"),
        workers=cfg.get("workers", 0),
        split_by=cfg.get("split_by", "hash"),
        **extra,
    )
