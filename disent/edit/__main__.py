"""``python -m disent.edit``: traversal edits, relighting and the measured tables.

Examples::

    # smile on the paper's manifolds (UV + Ni), a lambda progression strip per input
    python -m disent.edit traverse outputs/DATE/TIME synth:3 face.png photos/ --attribute smiling \\
        --strength 0.07 0.05 0.03 --out edits/
    # eyeglasses through the albedo only, barycenter with alpha = 1
    python -m disent.edit traverse RUN synth:3 --attribute eyeglasses --manifolds Ai --method barycenter --strength 1
    # relight: the light of another image, a named light, or a direction
    python -m disent.edit relight RUN target.png --source source.png --out relit/
    python -m disent.edit relight RUN synth:0 synth:1 --light <name> --method transfer ratio decode
    python -m disent.edit relight RUN synth:0 --direction 0.5 0.3 0.8 --intensity 1.0 --ambient 0.2
    # the measured tables and figures (a tool folder; python -m disent.report --publish FOLDER -> reports/edit/)
    python -m disent.edit measure RUN
    python -m disent.edit lights         # the light bank's names

Inputs: an image file (centre-cropped to a square and resized to the model's resolution;
use face crops framed like the training data), a folder of images, or ``synth:INDEX``
(a SynthFaces test face).  Pools: ``--pool synth`` (SynthFaces ``pool_<attr>``) or a
CelebA-style folder (``list_attr_celeba.txt``, read by :class:`disent.data.photos.folder.FolderFaces`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import NamedTuple

import torch

from disent.edit.traversal import ATTRIBUTES
from disent.images import over_max, save_image, strip
from disent.storage import tool_folder


# ----------------------------------------------------------------------------- images
class Input(NamedTuple):
    """An image to edit or relight, and how its pictures are written (:func:`disent.images.display`): ``srgb`` for
    a photo (encoded back as it was stored), ``rgb`` for a SynthFaces render (shown as the suite shows it)."""

    name: str
    image: torch.Tensor
    kind: str


def load_image(path: Path, resolution: int, align: bool = True, colour: tuple | None = None) -> torch.Tensor:
    """An image file as ``[3,R,R]`` linear radiance in [0,1] (decoded from sRGB), read and framed as the photos the
    models are applied to
    (:func:`disent.data.photos.pseudo_gt.aligned_crop`: EXIF rotation, gray/alpha/16-bit converted, the face
    aligned by its landmarks; ``align=False``: centre square crop).  With ``colour`` (a target of
    :func:`disent.eval.photos.colour_matched`) the whole pseudo-GT pipeline runs and the face (its ``mask_pseudo``)
    gets the target's colour statistics.  Raises ``pseudo_gt.Skip``."""
    from disent.data.photos import pseudo_gt as pg

    settings = pg.PseudoGTSettings(resolution=resolution)
    if colour is None:
        crop, _ = pg.aligned_crop(path, settings, align)
        return torch.from_numpy(pg.crop_pixels(crop))
    from disent.eval.photos import colour_matched

    maps = pg.process(pg.read_photo(path), settings)
    image = torch.from_numpy(pg.crop_pixels(maps["image"]))
    mask = torch.from_numpy(maps["mask_pseudo"].astype("float32")).reshape(1, 1, resolution, resolution)
    return colour_matched({"image": image[None], "mask_pseudo": mask}, colour)["image"][0]


def load_inputs(
    specs: list[str], resolution: int, seed: int = 0, align: bool = True, colour_match: bool = False
) -> list[Input]:
    """An :class:`Input` (``image [3,R,R]``, linear radiance) for each file, every image of each folder, and
    ``synth:INDEX``.  In a folder, a file that cannot be used is reported and left out; a single bad file is an
    error.  ``colour_match``: each photo's face gets SynthFaces' colour statistics (:func:`load_image`; needs
    alignment, so dlib)."""
    from disent.data.photos import pseudo_gt as pg
    from disent.data.photos.folder import list_images

    if align:
        try:
            import dlib  # noqa: F401
        except ImportError:
            if colour_match:
                raise SystemExit("error: --colour-match needs the face's landmark fit: pip install -e '.[photos]'")
            print("warning: face alignment needs dlib (pip install -e '.[photos]'); centre crops used")
            align = False
    if colour_match and not align:
        raise SystemExit("error: --colour-match needs the face aligned by its landmarks (drop --no-align)")
    colour = None
    if colour_match:
        from disent.eval.photos import colour_target

        colour = colour_target(resolution)
    out = []
    for spec in specs:
        if spec.startswith("synth:"):
            from disent.data import SynthFaces

            index = int(spec.split(":", 1)[1])
            image = SynthFaces("test", resolution=resolution, seed=seed)[index]["image"]
            out.append(Input(f"synth{index:05d}", image, "rgb"))
            continue
        p = Path(spec)
        if p.is_dir():
            files = list_images(p)
            if not files:
                raise SystemExit(f"error: no images ({'/'.join(pg.IMAGE_SUFFIXES)}) in folder {p}")
            for f in files:
                try:
                    out.append(Input(f.stem, load_image(f, resolution, align, colour), "srgb"))
                except pg.Skip as e:
                    print(f"skipped {f}: {e.reason}{f' ({e.detail})' if e.detail else ''}")
            if not out:
                raise SystemExit(f"error: no usable image in folder {p}")
        elif p.exists() or p.is_symlink():
            try:
                out.append(Input(p.stem, load_image(p, resolution, align, colour), "srgb"))
            except pg.Skip as e:
                raise SystemExit(f"error: {p}: {e.reason}{f' ({e.detail})' if e.detail else ''}") from None
        else:
            raise SystemExit(f"error: input {spec!r} is neither an image, a folder, nor synth:INDEX")
    return out


def load_model(run: str):
    from disent.models import load_run
    from disent.storage import CheckpointError

    try:
        model, cfg = load_run(run)
    except (FileNotFoundError, ValueError, CheckpointError) as e:  # unknown, mismatched or unreadable: one line
        raise SystemExit(f"error: {e}") from None
    return model, int(getattr(model, "resolution", 64))


# ----------------------------------------------------------------------------- pools
def build_pool(model, attribute: str, pool: str, size: int, resolution: int, seed: int):
    from disent.data import collate
    from disent.edit.traversal import encode_pool

    if pool == "synth":
        from disent.data import SynthFaces

        data = SynthFaces(split=f"pool_{attribute}", resolution=resolution, seed=seed, size=size)
    else:
        from disent.data.photos.folder import FolderFaces

        data = FolderFaces(pool, split=f"pool_{attribute}", resolution=resolution, seed=seed, size=size)
    batch = collate([data[i] for i in range(len(data))])
    return encode_pool(model, batch["image"], batch["attrs"][attribute], attribute)


# ----------------------------------------------------------------------------- commands
@torch.no_grad()
def cmd_traverse(a) -> None:
    from disent.edit.traversal import default_manifolds, traverse

    model, R = load_model(a.run)
    names = getattr(model, "CODE_NAMES", ())
    bad = [m for m in a.manifolds or () if m not in names]
    if bad:
        raise SystemExit(
            f"error: --manifolds {' '.join(bad)}: not a code of this {type(model).__name__.lower()} "
            f"model; its codes are {', '.join(names)}"
        )
    inputs = load_inputs(a.inputs, R, a.seed, a.align, a.colour_match)
    pool = build_pool(model, a.attribute, a.pool, a.pool_size, R, a.seed)
    images = torch.stack([x.image for x in inputs])
    codes = model.encode(images)
    manifolds = tuple(a.manifolds or default_manifolds(codes, a.attribute))
    recon = model.decode(codes)["recon"]
    edits = [model.decode(traverse(codes, pool, manifolds, a.method, s, add=not a.remove))["recon"] for s in a.strength]
    out = tool_folder("edit", a.out)
    key = "lam" if a.method == "dmt" else "alpha"
    tag = f"{'remove' if a.remove else 'add'}_{a.attribute}_{'+'.join(manifolds)}_{a.method}"
    for i, (name, x, kind) in enumerate(inputs):
        for s, e in zip(a.strength, edits):
            save_image(e[i], out / f"{name}_{tag}_{key}{s:g}.png", kind)
        save_image(strip([x, recon[i]] + [e[i] for e in edits], kind=kind), out / f"{name}_{tag}_strip.png")
    print(
        f"{len(inputs)} image(s): {tag}, {key} = {list(a.strength)}; strips (input | reconstruction | "
        f"edits) and edits in {out}/"
    )


def source_light(a, model, R) -> tuple[str, torch.Tensor]:
    from disent.edit.relight import directional_light, named_light

    if a.source:
        ((name, img, _),) = load_inputs([a.source], R, a.seed, a.align, a.colour_match)
        return f"from_{name}", model(img[None])["sh"]
    if a.light:
        return a.light, named_light(a.light)
    if a.direction:
        return "dir_" + "_".join(f"{v:g}" for v in a.direction), directional_light(a.direction, a.intensity, a.ambient)
    raise SystemExit("relight needs --source IMAGE, --light NAME or --direction X Y Z")


@torch.no_grad()
def cmd_relight(a) -> None:
    from disent.edit.relight import relight
    from disent.render import sh_shading

    model, R = load_model(a.run)
    inputs = load_inputs(a.inputs, R, a.seed, a.align, a.colour_match)
    label, sh = source_light(a, model, R)
    images = torch.stack([x.image for x in inputs])
    out = tool_folder("edit", a.out)
    results = {m: relight(model, images, sh, m) for m in a.method}
    est = model(images)
    S_transfer = sh_shading(est["normal"], sh.expand(len(images), -1, -1))
    for i, (name, x, kind) in enumerate(inputs):
        for m, r in results.items():
            save_image(r[i], out / f"{name}_{m}_{label}.png", kind)
        save_image(
            strip(
                [x, over_max(est["shading"][i]), over_max(S_transfer[i])] + [results[m][i] for m in a.method],
                kind=kind,
            ),
            out / f"{name}_relight_{label}_strip.png",
        )
    print(
        f"{len(inputs)} image(s) relit ({label}) by {', '.join(a.method)}; strips (input | S_target | "
        f"S_transfer | results) in {out}/"
    )


def cmd_lights(a) -> None:
    from disent.data import LIGHT_BANK

    for name in sorted(LIGHT_BANK):
        print(name)


def cmd_measure(a) -> None:
    from disent.edit.measure import run_measurements

    run_measurements(a)


def main(argv=None) -> None:
    """The four subcommands' options, then the one that was named runs (one argparse table: it reads better whole
    than cut into a function per subcommand)."""
    p = argparse.ArgumentParser(prog="python -m disent.edit", description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    common.add_argument(
        "--no-align",
        dest="align",
        action="store_false",
        help="centre-crop photos instead of aligning the face by its landmarks as in training",
    )
    common.add_argument(
        "--colour-match",
        action="store_true",
        help="give each photo's face (its pseudo-GT mask) the colour statistics of SynthFaces' training faces "
        "before the model reads it (needs dlib); outputs keep the matched colours. Its effect on the bundled photos: "
        "reports/appendix/photos.md",
    )
    run_help = "run folder, checkpoint, or a shipped model: explicit, implicit, baseline (disent/weights/)"

    t = sub.add_parser("traverse", parents=[common], help="move faces along an attribute (DMT or barycenter)")
    t.add_argument("run", help=run_help)
    t.add_argument("inputs", nargs="+", help="image files, folders, or synth:INDEX")
    t.add_argument("--attribute", required=True, choices=ATTRIBUTES)
    t.add_argument("--manifolds", nargs="+", help="codes to move (default: the paper's choice for the attribute)")
    t.add_argument("--method", default="dmt", choices=("dmt", "barycenter"))
    t.add_argument(
        "--strength",
        nargs="+",
        type=float,
        default=[0.07, 0.05, 0.03],
        help="lambda for dmt (smaller moves further; the paper's 0.07 0.05 0.03), alpha for barycenter",
    )
    t.add_argument("--remove", action="store_true", help="move away from the attribute instead")
    t.add_argument("--pool", default="synth", help="'synth' or a CelebA-style folder")
    t.add_argument("--pool-size", type=int, default=400)
    t.add_argument("--out", default=None, help="output folder (default: outputs/edit/<date>/<time>-<pid>/)")
    t.add_argument("--seed", type=int, default=0)
    t.set_defaults(fn=cmd_traverse)

    r = sub.add_parser("relight", parents=[common], help="relight faces (transfer with detailed albedo, ratio, decode)")
    r.add_argument("run", help=run_help)
    r.add_argument("inputs", nargs="+", help="target image files, folders, or synth:INDEX")
    r.add_argument("--source", help="image whose estimated light is transferred")
    r.add_argument("--light", help="a light of the bank (see: python -m disent.edit lights)")
    r.add_argument("--direction", nargs=3, type=float, help="distant light direction, camera frame (+z to camera)")
    r.add_argument("--intensity", type=float, default=1.0)
    r.add_argument("--ambient", type=float, default=0.2)
    r.add_argument("--method", nargs="+", default=["transfer"], choices=("transfer", "ratio", "decode"))
    r.add_argument("--out", default=None, help="output folder (default: outputs/edit/<date>/<time>-<pid>/)")
    r.add_argument("--seed", type=int, default=0)
    r.set_defaults(fn=cmd_relight)

    m = sub.add_parser("measure", parents=[common], help="the measured traversal and relighting tables on SynthFaces")
    m.add_argument("run", help=run_help)
    m.add_argument(
        "--out",
        default=None,
        help="output folder (default: outputs/edit/<date>/<time>-<pid>/); "
        "python -m disent.report --publish OUT copies it to reports/edit/",
    )
    m.add_argument("--attributes", nargs="+", default=list(ATTRIBUTES), choices=ATTRIBUTES)
    m.add_argument("--pool-size", type=int, default=200)
    m.add_argument("--sources", type=int, default=16)
    m.add_argument("--lambdas", nargs="+", type=float, default=None)
    m.add_argument("--alphas", nargs="+", type=float, default=None)
    m.add_argument(
        "--background",
        action="store_true",
        help="a diagnostic: the background code joins the manifold sets (written to <name>_background/)",
    )
    m.add_argument(
        "--measure-net",
        default=None,
        help="a trained measuring net (default: the shipped "
        "disent/weights/measure_net.pt; trained into the output folder when missing)",
    )
    m.add_argument("--train-size", type=int, default=4000)
    m.add_argument("--train-steps", type=int, default=3000)
    m.add_argument("--relight-faces", type=int, default=8)
    m.add_argument("--seed", type=int, default=0)
    m.add_argument(
        "--no-figures", action="store_true", help="tables and JSON only (e.g. for the seeds of a setting: ~7 MB less)"
    )
    m.set_defaults(fn=cmd_measure)

    lp = sub.add_parser("lights", help="list the light bank")
    lp.set_defaults(fn=cmd_lights)

    a = p.parse_args(argv)
    if getattr(a, "threads", None):
        torch.set_num_threads(a.threads)
    a.fn(a)


if __name__ == "__main__":
    main(sys.argv[1:])
