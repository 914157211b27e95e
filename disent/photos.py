"""``python -m disent.photos PATH [PATH ...]``: your own photos through the suite in one command.

    python -m disent.photos ~/portraits                 # the shipped explicit model
    python -m disent.photos a.jpg b.png --run implicit  # a shipped name, a run folder or a checkpoint

Every image file under each PATH goes through the pseudo-ground-truth pipeline
(:mod:`disent.data.photos.pseudo_gt`: EXIF rotation, landmarks, the training crop, the morphable-model fit) and
then through a trained model.  Into a run folder (``--out``, default ``outputs/decompose/<date>/<time>-<pid>``)
it writes, per photo ``NNN_<name>/``: ``crop.png``, ``normal_pseudo.png``, ``mask_pseudo.png``,
``landmarks.json`` (the 68 points in the original photo's pixels and in the crop), the decomposition
``recon.png albedo.png normal.png shading.png matte.png`` and ``relit_<light>.png`` (lighting transfer with
detailed albedo, Sec. 5.3), the colour pictures sRGB-encoded as the photo was (the models read and write linear
radiance); for the folder, ``decomposition.png`` (one row per photo) and ``summary.json``
with every file used or skipped and why.  Bad files are reported and left out; they never stop the batch.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from disent.data.photos import pseudo_gt as pg
from disent.images import over_max, save_image
from disent.storage import tool_folder

RELIGHT = ("flash_az-60", "top", "flash_az+60")  # named lights of the bank (python -m disent.edit lights)
SHOWN = 16  # rows of decomposition.png


def collect(paths: list[str]) -> list[Path]:
    """Image files of each folder (recursively) and each file given; a missing PATH is an error."""
    from disent.data.photos.folder import list_images

    files = []
    for p in map(Path, paths):
        if p.is_dir():
            files += list_images(p)
        elif p.exists() or p.is_symlink():
            files.append(p)
        else:
            raise SystemExit(f"error: {p} does not exist")
    if not files:
        raise SystemExit(f"error: no image files ({'/'.join(pg.IMAGE_SUFFIXES)}) under {', '.join(paths)}")
    return files


def faces_choice(text: str):
    if text in ("largest", "all", "skip"):
        return text
    if text.isdigit():
        return int(text)
    raise argparse.ArgumentTypeError(f"{text!r}: choose largest, all, skip or a face number (0: the largest)")


def run_pipeline(files, faces, resolution: int, upsample: int, cache_dir, workers: int) -> list:
    """Pseudo-GT records of ``files`` for the face choice ``faces``; with ``all``, one more record for each
    further face of a photo with several (``Record.face`` says which)."""
    base = dict(resolution=resolution, upsample=upsample)
    if faces == "skip":
        settings = pg.PseudoGTSettings(**base, multiple_faces="skip")
    else:
        settings = pg.PseudoGTSettings(**base, face=faces if isinstance(faces, int) else 0)
    try:
        records, _ = pg.prepare(files, settings, cache_dir, workers=workers, log_summary=False)
        if faces == "all":
            n_faces = {r.path: len(pg.load_cached(r)["faces"]) for r in records if r.used}
            for k in range(1, max(n_faces.values(), default=1)):
                more = [p for p, n in n_faces.items() if n > k]
                records += pg.prepare(
                    more, pg.PseudoGTSettings(**base, face=k), cache_dir, workers=workers, log_summary=False
                )[0]
    except (ImportError, FileNotFoundError) as e:  # dlib or its landmark model missing: a setup error
        raise SystemExit(
            f"error: the photo pipeline needs dlib and its landmark model (pip install -e '.[photos]'): {e}"
        ) from None
    return records


def photo_landmarks(arrays: dict) -> dict:
    """The 68 landmarks in the crop and, through the inverse alignment, in the original photo's pixels."""
    crop = arrays["landmarks"].astype(np.float64)
    M = arrays["align"].astype(np.float64)  # photo -> crop, 3x3
    photo = (np.c_[crop, np.ones(len(crop))] @ np.linalg.inv(M).T)[:, :2]
    return {
        "photo_xy": np.round(photo, 2).tolist(),
        "crop_xy": np.round(crop, 2).tolist(),
        "fit_residual_px": float(arrays["residual_px"]),
    }


@torch.no_grad()
def write_photo(folder: Path, arrays: dict, batch: dict, out: dict, relit: dict, i: int) -> None:
    """One photo's files; the pictures in colour (crop, recon, albedo, relit) sRGB-encoded as the photo was."""
    folder.mkdir(parents=True, exist_ok=True)
    save_image(batch["image"][i], folder / "crop.png", "srgb")
    save_image(batch["normal_pseudo"][i], folder / "normal_pseudo.png", "normal")
    save_image(batch["mask_pseudo"][i], folder / "mask_pseudo.png", "gray")
    (folder / "landmarks.json").write_text(json.dumps(photo_landmarks(arrays)) + "\n")
    save_image(out["recon"][i], folder / "recon.png", "srgb")
    for key, kind in (("albedo", "srgb"), ("normal", "normal"), ("matte", "gray")):
        if key in out:
            save_image(out[key][i], folder / f"{key}.png", kind)
    if "shading" in out:
        s = out["shading"][i]
        save_image(over_max(s), folder / "shading.png")  # shown normalised
    for name, x in relit.items():
        save_image(x[i], folder / f"relit_{name}.png", "srgb")


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="python -m disent.photos",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__.split("\n\n", 1)[1],
    )
    ap.add_argument("paths", nargs="+", help="image files and folders")
    ap.add_argument(
        "--run", default="explicit", help="shipped model name, run folder or checkpoint (default: explicit)"
    )
    ap.add_argument("--out", default=None, help="output folder (default: outputs/decompose/<date>/<time>-<pid>)")
    ap.add_argument(
        "--faces",
        default="largest",
        type=faces_choice,
        help="a photo with several faces: largest (default), all, skip, or N (the N-th by size, 0: largest)",
    )
    ap.add_argument("--upsample", type=int, default=1, help="face detector upsampling (finds smaller faces)")
    ap.add_argument("--workers", type=int, default=0, help="processes for the pseudo-GT pipeline (0: this one)")
    ap.add_argument("--cache-dir", default=None, help="pseudo-GT cache (default: ~/.cache/disent/pseudo_gt)")
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    ap.add_argument(
        "--colour-match",
        action="store_true",
        help="give each face (its mask_pseudo) the colour statistics of SynthFaces' training faces before the model "
        "reads it (disent.eval.photos.colour_matched); crop.png and the outputs keep the matched colours",
    )
    return ap


def decompose(model, used: list, a, out_dir: Path, R: int) -> list[dict]:
    """The model's layers and relit images of the photos it could use, one folder each, and the figures of the
    first ``SHOWN``; returns their rows of ``summary.json``."""
    from disent.edit.relight import named_light, relight
    from disent.eval.photos import colour_matched, colour_target, figures, photo_batch

    batch = photo_batch(used)
    if a.colour_match:
        batch = colour_matched(batch, colour_target(R))
    est = model(batch["image"])
    relit, rows = {}, []
    if "sh" in est:
        relit = {n: relight(model, batch["image"], named_light(n).expand(len(used), -1, -1)) for n in RELIGHT}
    for i, r in enumerate(used):
        folder = out_dir / f"{i:03d}_{Path(r.path).stem}{f'_face{r.face}' if r.face else ''}"
        arrays = pg.load_cached(r)
        write_photo(folder, arrays, batch, est, relit, i)
        rows.append(
            {
                "path": r.path,
                "used": True,
                "face": r.face,
                "folder": folder.name,
                "notes": r.notes,
                "fit_residual_px": r.residual_px,
                "faces_found": [
                    {"box": [round(float(v), 1) for v in f[:4]], "score": round(float(f[4]), 3)}
                    for f in arrays["faces"]
                ],
            }
        )
    shown = used[:SHOWN]
    tag = Path(a.run).name  # the figures' titles name the model
    figures(model, {k: v[:SHOWN] for k, v in batch.items()}, [Path(r.path).stem for r in shown], out_dir, tag)
    (out_dir / f"decomposition_{tag}.png").replace(out_dir / "decomposition.png")
    if (out_dir / f"relight_{tag}.png").exists():
        (out_dir / f"relight_{tag}.png").replace(out_dir / "relight.png")
    return rows


def main(argv=None) -> None:
    ap = parser()
    a = ap.parse_args(argv)
    if a.workers < 0 or a.threads < 1 or a.upsample < 0:
        ap.error("--workers must be >= 0, --threads >= 1, --upsample >= 0")
    torch.set_num_threads(a.threads)
    from disent.edit.__main__ import load_model

    files = collect(a.paths)  # a wrong path stops here, before the model is loaded
    model, R = load_model(a.run)
    out_dir = tool_folder("decompose", a.out)
    records = run_pipeline(files, a.faces, R, a.upsample, a.cache_dir, a.workers)
    summary = pg.summarize(records)
    used = [r for r in records if r.used]
    report = {
        "run": a.run,
        "faces": a.faces,
        "upsample": a.upsample,
        "colour_match": a.colour_match,
        "summary": summary,
        "photos": [],
    }
    if used:
        report["photos"] = decompose(model, used, a, out_dir, R)
    report["photos"] += [
        {"path": r.path, "used": False, "face": r.face, "reason": r.reason, "detail": r.detail}
        for r in records
        if not r.used
    ]
    (out_dir / "summary.json").write_text(json.dumps(report, indent=2) + "\n")
    print(pg.format_summary(summary))
    for r in records:
        if not r.used:
            print(f"  skipped {r.path}: {r.reason}{f' ({r.detail})' if r.detail else ''}")
    print(
        f"{len(used)} photo(s) decomposed by {a.run} -> {out_dir}/ "
        "(summary.json, decomposition.png, one folder per photo)"
    )
    if not used:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
