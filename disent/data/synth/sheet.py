"""Contact sheet of SynthFaces: ``python -m disent.data.synth.sheet [--out PATH] [--resolution 64]``.

Rows: samples with their ground-truth layers; pseudo ground truth beside the truth; each
attribute off and on; the light bank on one face; the optional effects.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from disent.images import display, strip
from disent.storage import tool_folder

from . import LIGHT_NAMES, SynthFaces
from .scenes import ATTRIBUTES, EFFECTS


def contact_sheet(resolution: int = 64, seed: int = 0) -> tuple[torch.Tensor, list[str]]:
    train = SynthFaces("train", resolution, seed)
    rows, labels = [], []
    b = train.get_batch(range(0, 64, 8))
    layers = (
        "image",
        "background",
        "matte",
        "mask_face",
        "albedo",
        "shading",
        "normal",
        "uv",
        "albedo_uv",
        "normal_uv",
    )
    for k in range(6):  # samples and their GT layers, then the pseudo-GT beside
        tiles = []
        for name in layers:
            v = b[name][k]
            tiles.append(display(v, "normal" if name.startswith("normal") else "rgb"))
        tiles += [
            display(b["normal_pseudo"][k], "normal"),
            display(b["mask_pseudo"][k]),
            display(b["uv_pseudo"][k]),
            display(b["normal_uv_pseudo"][k], "normal"),
        ]
        rows.append(strip(tiles))
    labels.append(
        "GT: image bg matte face-region albedo shading normal uv albedo_uv normal_uv | pseudo: normal mask uv normal_uv"
    )
    tiles = []
    for a in ATTRIBUTES:  # each attribute off / on, everything else fixed
        for s in (0.0, 1.0):
            tiles.append(train.sample(8, light="flash_az+0", **{a: s})["image"])
    rows.append(strip(tiles))
    labels.append("attributes off/on: " + ", ".join(ATTRIBUTES))
    bank = SynthFaces("lightbank", resolution, seed)
    lb = bank.get_batch(range(len(LIGHT_NAMES) * 1, len(LIGHT_NAMES) * 2))  # identity 0, frontal pose
    n = len(LIGHT_NAMES) // 2
    rows.append(strip(list(lb["image"][:n])))
    rows.append(strip(list(lb["image"][n : 2 * n])))
    labels.append("light bank: " + " ".join(LIGHT_NAMES))
    tiles = [train.sample(5)["image"]] + [train.sample(5, effects={e: 1.0})["image"] for e in EFFECTS]
    tiles += [train.sample(6)["image"]] + [train.sample(6, effects={e: 0.5})["image"] for e in EFFECTS]
    rows.append(strip(tiles))
    labels.append("effects at severity 1 and 0.5: none " + " ".join(EFFECTS))
    W = max(r.shape[2] for r in rows)
    rows = [torch.cat([r, torch.ones(3, r.shape[1], W - r.shape[2])], 2) for r in rows]
    sep = torch.ones(3, 4, W)
    sheet = torch.cat([x for r in rows for x in (r, sep)][:-1], 1)
    return sheet, labels


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument(
        "--out",
        type=Path,
        default=None,
        help="PNG to write (default: synthfaces.png in a new tool folder "
        "outputs/sheet/<date>/<time>-<pid>/, published to reports/figures/)",
    )
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--zoom", type=int, default=2)
    args = ap.parse_args(argv)
    if args.out is not None and args.out.suffix.lower() != ".png":
        ap.error(f"--out {args.out}: give a .png file to write")
    from disent.images import pyplot

    plt = pyplot()

    sheet, labels = contact_sheet(args.resolution, args.seed)
    sheet = sheet.repeat_interleave(args.zoom, 1).repeat_interleave(args.zoom, 2)
    out = args.out or tool_folder("sheet") / "synthfaces.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    plt.imsave(out, sheet.permute(1, 2, 0).numpy())
    print(f"wrote {out}")
    for line in labels:
        print(" ", line)


if __name__ == "__main__":
    main()
