"""Edits and relighting measured on SynthFaces, where the truth is known (beyond the paper).

**Traversal.**  Source faces without the attribute (test split) are moved towards it on a
manifold choice, with DMT (lambda) or the barycenter (alpha), and decoded.  A
:class:`~disent.edit.classifier.MeasureNet` trained on the generator's truth reads

* ``step``: how far the codes moved along the pools' mean difference (1 = all the way from
  the negatives' mean to the positives'), which puts lambda and alpha on one scale;
* ``success``: the fraction of edited faces it calls positive, and ``gain``: the mean rise of
  its attribute probability over the unedited reconstruction;
* leakage, each divided by its spread between two random faces so that they add up:
  ``d_light`` (its SH estimate), ``d_pose`` (its yaw/pitch/roll), ``d_identity`` (its estimate
  of the generator's identity parameters), ``d_bg`` (mean absolute pixel change outside the
  true matte), and ``d_attrs`` (the mean change of the other three attribute probabilities,
  not divided).  ``leakage`` is their mean, and ``gain_per_leak`` the ratio the paper's
  manifold choice should maximise.

Every number is taken against the **unedited reconstruction**, so model error is not counted
as leakage.  ``truth`` rows are the generator's own counterfactual (same face, attribute on):
what a perfect edit scores under the same reader; ``truth reconstructed`` rows, the model's reconstruction of
those faces: how often what the model can draw at all reads as the attribute, the most an edit can reach.
With no reader, against the generator's change of the same faces (attribute on, less off): ``drawn_share``, the
share of that change an edit draws, and ``off_target``, the energy of the edit's change off that change, over its
energy (:func:`drawn_share`, :func:`off_target_share`; ``_face``: inside the face region).

**Relighting.**  Target faces re-rendered by the generator under a light of the bank are the
ground truth; the light comes from the model's estimate on a *different* face under that light
(the paper's setting).  PSNR/SSIM over the image, inside the true matte (the head) and inside the
face region ``mask_face`` (the skin the model's matte is trained to cover; there also after one
brightness scale per image), for transfer with
detailed albedo, naive ratio, decoding with the swapped ``Z_L``, and the unrelit input.
``oracle`` applies the transfer formulas to the generator's true intrinsics and light.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import torch

from disent.data import get_batch
from disent.edit.classifier import MeasureNet
from disent.edit.relight import ratio_relight, transfer_lighting, with_light
from disent.edit.traversal import ATTRIBUTES, DEFAULT_MANIFOLDS, FACE_CODES, encode_pool, model_kind, traverse
from disent.eval.metrics import optimal_scale, reconstruction_metrics
from disent.regions import face_mask
from disent.render import sh_shading

DEFAULT_LAMBDAS = (1.0, 0.3, 0.07, 0.05, 0.03, 0.01)  # the paper's 0.07-0.01, and two smaller steps
DEFAULT_ALPHAS = (0.5, 1.0, 2.0)
SEMANTIC_SHAPE = 17  # the face model's named shape components (the rest are fine random fields)
IDENTITY_READABLE = 0.7  # held-out identity RMSE (in std) below which d_identity is trusted
PSNR_CAP = 100.0  # dB; float32 round-off of an exact answer lands above it
LEAK_KEYS = ("d_light", "d_pose", "d_identity", "d_attrs", "d_bg")
# the drawn shares an edit row carries (over the image, inside the face region), and the keys claim_summary gives
# each over the strengths: its sum per unit of the summed leakage, and its best value
DRAWN_READINGS = {
    "drawn_share": ("drawn_per_leak", "best_drawn"),
    "drawn_share_face": ("drawn_face_per_leak", "best_drawn_face"),
}
# the reader-free leakage beside each drawn share (off_target_share), and the claims' key of the drawn shares summed
# over the strengths per unit of it summed
OFF_TARGET_READINGS = {
    "drawn_share": ("off_target", "drawn_per_off_target"),
    "drawn_share_face": ("off_target_face", "drawn_face_per_off_target"),
}


def manifold_choices(kind: str, attribute: str, background: bool = False) -> dict[str, tuple[str, ...]]:
    """The paper's choice, each face manifold alone, and all of them (duplicates dropped); with ``background``
    also the background code alone and with every face code (a diagnostic: an attribute the image shows outside
    the face, such as hair, lives there)."""
    face = FACE_CODES[kind]
    choices = {"paper": DEFAULT_MANIFOLDS[kind][attribute]}
    for m in face:
        choices[m] = (m,)
    choices["all"] = face
    if background and kind != "baseline":
        choices["bg"], choices["all+bg"] = ("bg",), (*face, "bg")
    out, seen = {}, set()
    for label, ms in choices.items():
        key = tuple(sorted(ms))
        if key in seen:
            continue
        seen.add(key)
        out[label if label != "paper" else "paper:" + "+".join(ms)] = ms
    return out


def identity_params(data, indices) -> torch.Tensor:
    """The generator's identity: its semantic face-shape coefficients and skin colour, ``[N, 20]``."""
    p = data.params(list(indices))
    return torch.cat([p["alpha"][:, :SEMANTIC_SHAPE], p["skin"]], 1).float()


def attr_matrix(batch: dict) -> torch.Tensor:
    return torch.stack([batch["attrs"][a].float() for a in ATTRIBUTES], 1)


@torch.no_grad()
def read(net: MeasureNet, images: torch.Tensor, batch_size: int = 128) -> dict:
    outs = [net(images[i : i + batch_size].clamp(0, 1)) for i in range(0, len(images), batch_size)]
    out = {k: torch.cat([o[k] for o in outs]) for k in outs[0]}
    out["p"] = torch.sigmoid(out.pop("attr_logits"))
    return out


@torch.no_grad()
def population_spread(net: MeasureNet, batch: dict) -> dict:
    """The yardsticks leakage is divided by, from a sample of the population."""
    r = read(net, batch["image"])
    perm = torch.roll(torch.arange(len(batch["image"])), 1)
    spread = {
        "light": (r["sh"] - r["sh"][perm]).pow(2).flatten(1).mean(1).sqrt().mean().item(),
        "pose": (r["pose"] - r["pose"][perm]).abs().mean().item(),
        "bg": (batch["background"] - batch["background"][perm]).abs().mean().item(),
    }
    if "identity" in r:
        spread["identity"] = (r["identity"] - r["identity"][perm]).norm(dim=1).mean().item()
    return spread


def leakage(before: dict, after: dict, img_before, img_after, matte, attribute: str, spread: dict) -> dict:
    """Per-image changes between two readings (see the module docstring), ``[B]`` each."""
    others = [i for i, a in enumerate(ATTRIBUTES) if a != attribute]
    out = {
        "d_light": (after["sh"] - before["sh"]).pow(2).flatten(1).mean(1).sqrt() / spread["light"],
        "d_pose": (after["pose"] - before["pose"]).abs().mean(1) / spread["pose"],
        "d_attrs": (after["p"][:, others] - before["p"][:, others]).abs().mean(1),
    }
    outside = (matte < 0.5).float()
    out["d_bg"] = (
        ((img_after - img_before).abs() * outside).sum((1, 2, 3))
        / (3 * outside.sum((1, 2, 3)).clamp_min(1))
        / spread["bg"]
    )
    if "identity" in before and "identity" in spread:
        out["d_identity"] = (after["identity"] - before["identity"]).norm(dim=1) / spread["identity"]
    return out


def step_along_attribute(codes0: dict, codes: dict, pool, manifolds) -> float:
    """How far the codes moved along ``mean positives - mean negatives``, in units of that
    difference (barycenter traversal with alpha moves exactly alpha), averaged over manifolds
    and faces; it puts DMT's lambda on the barycenter's alpha scale."""
    steps = []
    for m in manifolds:
        d = pool.positives[m].mean(0) - pool.negatives[m].mean(0)
        steps.append(((codes[m] - codes0[m]).flatten(1) @ d / d.dot(d)).mean())
    return torch.stack(steps).mean().item()


def drawn_and_off_target(recon_off, recon_on, image_off, image_on, region=None) -> tuple[float, float]:
    """``(drawn share, off-target change)`` of a model's change ``D_m`` (between its reconstructions of the faces with
    and without the attribute, or an edit and the unedited reconstruction) against the generator's change ``D_t``
    (the same faces, lights and poses with the attribute on, less off), over the batch; with ``region``
    (``[B,1,H,W]``) only the change inside it counts (NaN, NaN where the attribute changes nothing there).
    See :func:`drawn_share` and :func:`off_target_share`."""
    true_change, model_change = image_on - image_off, recon_on - recon_off
    if region is not None:
        true_change, model_change = true_change * region, model_change * region
    energy = (true_change * true_change).sum()
    if energy <= 0:
        return math.nan, math.nan
    share = (model_change * true_change).sum() / energy
    return float(share), float((model_change - share * true_change).pow(2).sum() / energy)


def drawn_share(recon_off, recon_on, image_off, image_on, region=None) -> float:
    """How much of an attribute's true change a model draws, with no reader: ``<D_m, D_t> / <D_t, D_t>`` (1: all of
    it; 0: none; :func:`drawn_and_off_target`)."""
    return drawn_and_off_target(recon_off, recon_on, image_off, image_on, region)[0]


def off_target_share(recon_off, recon_on, image_off, image_on, region=None) -> float:
    """Leakage with no reader: the energy of the part of the model's change ``D_m`` that is not along the true change
    ``D_t``, ``|D_m - s D_t|^2 / <D_t, D_t>`` with ``s`` the drawn share: 0 for an edit that changes only what the
    attribute changes, however strongly; light, pose, identity or background changes, and an attribute drawn in
    another place or shape, all count (:func:`drawn_and_off_target`)."""
    return drawn_and_off_target(recon_off, recon_on, image_off, image_on, region)[1]


def summarize(attribute, manifolds, method, strength, p0, r, leaks) -> dict:
    i = ATTRIBUTES.index(attribute)
    row = {
        "attribute": attribute,
        "manifolds": manifolds,
        "method": method,
        "strength": strength,
        "success": (r["p"][:, i] > 0.5).float().mean().item(),
        "gain": (r["p"][:, i] - p0).mean().item(),
    }
    row.update({k: v.mean().item() for k, v in leaks.items()})
    row["leakage"] = sum(row[k] for k in LEAK_KEYS if k in row) / sum(k in row for k in LEAK_KEYS)
    row["gain_per_leak"] = row["gain"] / row["leakage"] if row["leakage"] > 0 else math.nan
    return row


def _truth_rows(model, net, src, true_edit, recon0, attribute: str, spread: dict) -> tuple[list[dict], object]:
    """:func:`edit_table`'s rows for the true edit (``true_edit``: the sources rendered with the attribute on) and
    for the model's reconstruction of it, and ``shares(edited)``: how much of the true change an edit draws."""
    i_attr = ATTRIBUTES.index(attribute)
    r_in = read(net, src["image"])
    rt = read(net, true_edit["image"])
    leak = leakage(r_in, rt, src["image"], true_edit["image"], src["matte"], attribute, spread)
    row = summarize(attribute, "-", "truth", 1.0, r_in["p"][:, i_attr], rt, leak)
    # the face region of the faces with and without it: the paper's face masks leave hair out (Sec. 5.2,
    # Limitations), and SynthFaces greys a senior face's hair, which no face code reaches. change_in_face: the
    # share of the true change there, what a model drawing all of it there and nothing outside draws
    face = torch.maximum(src["mask_face"], true_edit["mask_face"])
    off, on = src["image"], true_edit["image"]
    rows = [{**row, "change_in_face": drawn_share(off, off + (on - off) * face, off, on)}]
    # what the model can draw at all: its reconstruction of the faces that truly have the attribute. An edit
    # cannot read as the attribute more often than this (beside the truth's own rate, the reader's recall)
    drawn = model.decode(model.encode(true_edit["image"]))["recon"]
    rd = read(net, drawn)
    leak = leakage(r_in, rd, src["image"], drawn, src["matte"], attribute, spread)
    row = summarize(attribute, "-", "truth reconstructed", 1.0, r_in["p"][:, i_attr], rd, leak)

    def shares(edited) -> dict:  # each drawn share, and its off-target change (OFF_TARGET_READINGS)
        out = {}
        for key, region in (("drawn_share", None), ("drawn_share_face", face)):
            out[key], out[OFF_TARGET_READINGS[key][0]] = drawn_and_off_target(recon0, edited, off, on, region)
        return out

    rows.append({**row, **shares(drawn)})
    return rows, shares


@torch.no_grad()
def edit_table(
    model,
    net: MeasureNet,
    data_cls,
    attribute: str,
    pool_size: int = 200,
    n_sources: int = 16,
    lambdas=DEFAULT_LAMBDAS,
    alphas=DEFAULT_ALPHAS,
    choices: dict | None = None,
    resolution: int = 64,
    seed: int = 0,
    truth_override=None,
    n_show: int = 4,
    read_identity: bool = True,
    background: bool = False,
) -> tuple[list[dict], dict]:
    """Rows of the traversal table for one attribute (see the module docstring), and the first
    ``n_show`` images of each setting (``input``, ``recon``, ``truth``, ``(label, method, strength)``).

    ``data_cls``: the :class:`~disent.data.SynthFaces` class (or one with its interface).
    ``truth_override(attribute) -> dict`` gives the generator overrides that switch the attribute
    on, for the ``truth`` row (omitted when None).  ``read_identity=False`` leaves ``d_identity`` out (for a
    measuring net whose held-out identity error is no better than guessing the mean).  ``background``: the
    background code joins the manifold sets (:func:`manifold_choices`).
    """
    kind = model_kind(dict.fromkeys(model.CODE_NAMES))
    choices = choices or manifold_choices(kind, attribute, background)
    extra = tuple(dict.fromkeys(c for ms in choices.values() for c in ms if c not in FACE_CODES[kind]))  # e.g. bg
    pool_data = data_cls(split=f"pool_{attribute}", resolution=resolution, seed=seed, size=pool_size)
    pool_batch = get_batch(pool_data, range(len(pool_data)))
    pool = encode_pool(model, pool_batch["image"], pool_batch["attrs"][attribute], attribute, extra_codes=extra)
    test = data_cls(split="test", resolution=resolution, seed=seed)
    candidates = get_batch(test, range(min(len(test), 20 * n_sources)))
    idx = torch.nonzero(candidates["attrs"][attribute] < 0.5).flatten()[:n_sources].tolist()
    src = get_batch(test, idx)
    spread = population_spread(net, pool_batch)
    if not read_identity:  # the reader cannot tell identities apart: leave d_identity out
        spread.pop("identity", None)
    codes0 = model.encode(src["image"])
    recon0 = model.decode(codes0)["recon"]
    r0 = read(net, recon0)
    i_attr = ATTRIBUTES.index(attribute)
    p0 = r0["p"][:, i_attr]
    leak = leakage(r0, r0, recon0, recon0, src["matte"], attribute, spread)
    rows = [summarize(attribute, "-", "reconstruction", 0.0, p0, r0, leak)]
    shown = {"input": src["image"][:n_show], "recon": recon0[:n_show]}
    shares = None
    if truth_override is not None:
        true_edit = get_batch(test, idx, **truth_override(attribute))
        truth_rows, shares = _truth_rows(model, net, src, true_edit, recon0, attribute, spread)
        rows += truth_rows
        shown["truth"] = true_edit["image"][:n_show]
    for label, manifolds in choices.items():
        for method, strengths in (("dmt", lambdas), ("barycenter", alphas)):
            for s in strengths:
                codes = traverse(codes0, pool, manifolds, method, s)
                edited = model.decode(codes)["recon"]
                r = read(net, edited)
                shown[(label, method, s)] = edited[:n_show]
                leak = leakage(r0, r, recon0, edited, src["matte"], attribute, spread)
                rows.append(summarize(attribute, label, method, s, p0, r, leak))
                rows[-1]["step"] = step_along_attribute(codes0, codes, pool, manifolds)
                if shares is not None:  # how much of the true change the edit draws, with no reader
                    rows[-1].update(shares(edited))
    return rows, shown


# ----------------------------------------------------------------------------- relighting
# where each relit image is scored against the generator's render: the whole image, the head (the true matte: face,
# hair, ears, neck) and the face region (``mask_face``: the skin a 3DMM covers, which the model's matte is trained
# to cover; transfer relights only under that matte and leaves the rest of the head as it was), and there after one
# brightness scale per image (``psnr_skin_scaled``). Inside a full matte, transfer's detailed albedo makes it the ratio
# image (A S' = I S' / S, Eqs. 2 and 4); the two differ only where the model's matte is not full (face_mask): Eq. 6
# blends the unrelit input in: the face region split there (``_full`` / ``_soft``, each scaled on its own pixels), and
# ``matte_full_share``, the face region's share under a full matte (disent.regions.face_mask)
RELIGHT_SCORES = (
    "psnr",
    "ssim",
    "psnr_face",
    "ssim_face",
    "psnr_skin",
    "ssim_skin",
    "psnr_skin_scaled",
    "psnr_skin_full_scaled",
    "psnr_skin_soft_scaled",
    "matte_full_share",
)


def scaled_psnr(pred: torch.Tensor, target: torch.Tensor, region: torch.Tensor) -> float:
    """PSNR (dB) inside ``region`` after one brightness scale per image fitted there, over the images with a pixel in
    it (NaN where none has)."""
    keep = region.flatten(1).any(1)
    if not keep.any():
        return math.nan
    pred, target, region = pred[keep], target[keep], region[keep]
    scale = optimal_scale(pred, target, region, (1, 2, 3))
    return reconstruction_metrics((scale * pred).clamp(0, 1), target, region)["psnr"]


@torch.no_grad()
def relight_table(
    model, data_cls, light_bank: dict, n_faces: int = 8, n_lights: int = 6, resolution: int = 64, seed: int = 0
) -> tuple[list[dict], dict]:
    """Relighting accuracy rows (see the module docstring) and one example batch for figures."""
    test = data_cls(split="test", resolution=resolution, seed=seed)
    names = sorted(light_bank)[:: max(1, len(light_bank) // n_lights)][:n_lights]
    targets = get_batch(test, range(n_faces))
    out_t = model(targets["image"])
    face = targets["mask_face"]
    full = face_mask(out_t["matte"]).to(face.dtype) * face
    full_share = (full.sum() / face.sum().clamp_min(1)).item()
    results: dict[str, list] = {}
    example = None
    for k, name in enumerate(names):
        sh = torch.as_tensor(light_bank[name], dtype=torch.float32).reshape(1, 3, 9)
        truth = get_batch(test, range(n_faces), sh=sh[0])
        # the source light: the model's estimate on other faces rendered under that light
        sources = get_batch(test, range(n_faces, 2 * n_faces), sh=sh[0])
        sh_src = model(sources["image"])["sh"]
        preds = {
            "transfer": transfer_lighting(
                targets["image"], out_t["normal"], out_t["shading"], out_t["matte"], sh_src, out_t["albedo"]
            ),
            "ratio": ratio_relight(targets["image"], out_t["normal"], out_t["sh"], sh_src),
            "decode": model.decode(with_light(out_t["codes"], sh_src))["recon"],
            "input": targets["image"],
            "oracle": transfer_lighting(
                targets["image"],
                targets["normal"],
                targets["shading"],
                targets["matte"],
                sh.expand(n_faces, -1, -1),
                targets["albedo"],
            ),
        }
        for method, pred in preds.items():
            pred = pred.clamp(0, 1)
            whole = reconstruction_metrics(pred, truth["image"])
            head = reconstruction_metrics(pred, truth["image"], truth["matte"])
            skin = reconstruction_metrics(pred, truth["image"], face)
            # the same after one brightness scale per image: the light's intensity, read from another face, is
            # confounded with that face's albedo; what is left is the light's direction and colour
            aligned = [scaled_psnr(pred, truth["image"], m) for m in (face, full, face - full)]
            results.setdefault(method, []).append(
                (whole["psnr"], whole["ssim"], head["psnr"], head["ssim"], skin["psnr"], skin["ssim"], *aligned)
                + (full_share,)
            )
        if example is None:
            example = {
                "target": targets["image"],
                "source": sources["image"],
                "truth": truth["image"],
                "S_target": out_t["shading"],
                "S_transfer": sh_shading(out_t["normal"], sh_src),
                **{m: p.clamp(0, 1) for m, p in preds.items()},
                "light": name,
            }
    rows = []
    for method, vals in results.items():
        t = torch.tensor(vals, dtype=torch.float64)
        psnr = [k for k, key in enumerate(RELIGHT_SCORES) if key.startswith("psnr")]
        t[:, psnr] = t[:, psnr].clamp(max=PSNR_CAP)  # exact up to float error (or inf): the cap
        rows.append(
            {
                "method": method,
                **{key: t[:, k].nanmean().item() for k, key in enumerate(RELIGHT_SCORES)},
                "lights": len(names),
                "faces": n_faces,
            }
        )
    return rows, example


# ----------------------------------------------------------------------------- the report
def markdown_table(rows: list[dict], keys: list[str]) -> str:
    fmt = lambda v: f"{v:.4g}" if isinstance(v, float) else str(v)  # noqa: E731
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(fmt(r.get(k, "")) for k in keys) + " |" for r in rows]
    return "\n".join(lines)


def claim_summary(rows: list[dict]) -> list[dict]:
    """Per attribute, method and manifold choice: total gain over total leakage across its
    strengths, ranked within the attribute and method (``rank`` 1 = most success per leakage); where the rows
    carry :func:`drawn_share`, the same without the reader: ``drawn_per_leak`` (the drawn shares summed over the
    strengths, over the summed leakage) and ``best_drawn``; ``drawn_face_per_leak`` and ``best_drawn_face``, the
    same inside the face region (:data:`DRAWN_READINGS`); where they carry :func:`off_target_share` too, with no
    reader at all: ``drawn_per_off_target`` and ``drawn_face_per_off_target``, the drawn shares summed over the
    strengths over the summed off-target changes (:data:`OFF_TARGET_READINGS`)."""
    out = []
    for attribute in dict.fromkeys(r["attribute"] for r in rows):
        for method in ("dmt", "barycenter"):
            sel = [r for r in rows if r["attribute"] == attribute and r["method"] == method]
            group = []
            for label in dict.fromkeys(r["manifolds"] for r in sel):
                rs = [r for r in sel if r["manifolds"] == label]
                gain, leak = sum(r["gain"] for r in rs), sum(r["leakage"] for r in rs)
                group.append(
                    {
                        "attribute": attribute,
                        "method": method,
                        "manifolds": label,
                        "gain_sum": gain,
                        "leakage_sum": leak,
                        "gain_per_leak": gain / leak if leak > 0 else math.nan,
                        "best_success": max(r["success"] for r in rs),
                    }
                )
                for key, (per_leak, best) in DRAWN_READINGS.items():
                    if all(key in r for r in rs):
                        drawn = sum(r[key] for r in rs)
                        group[-1][per_leak] = drawn / leak if leak > 0 else math.nan
                        group[-1][best] = max(r[key] for r in rs)
                        off_key, per_off = OFF_TARGET_READINGS[key]
                        if all(off_key in r for r in rs):
                            off = sum(r[off_key] for r in rs)
                            group[-1][per_off] = drawn / off if off > 0 else math.nan
            order = sorted(group, key=lambda g: -g["gain_per_leak"] if math.isfinite(g["gain_per_leak"]) else math.inf)
            for g in group:
                g["rank"] = order.index(g) + 1
            out += order
    return out


def plot_success_vs_leakage(rows: list[dict], path) -> None:
    from disent.images import pyplot

    plt = pyplot()

    attributes = list(dict.fromkeys(r["attribute"] for r in rows))
    fig, axes = plt.subplots(1, len(attributes), figsize=(4.2 * len(attributes), 3.6), squeeze=False)
    for ax, attribute in zip(axes[0], attributes):
        for method, style in (("dmt", "-o"), ("barycenter", "--s")):
            sel = [r for r in rows if r["attribute"] == attribute and r["method"] == method]
            for k, label in enumerate(dict.fromkeys(r["manifolds"] for r in sel)):
                rs = [r for r in sel if r["manifolds"] == label]
                ax.plot(
                    [r["leakage"] for r in rs],
                    [r["gain"] for r in rs],
                    style,
                    color=f"C{k}",
                    ms=4,
                    label=f"{label} {method}",
                    lw=2.2 if label.startswith("paper") else 1.0,
                )
        for r in rows:
            if r["attribute"] == attribute and r["method"] == "truth":
                ax.plot([r["leakage"]], [r["gain"]], "k*", ms=12, label="generator truth")
        ax.set_title(attribute)
        ax.set_xlabel("leakage (mean normalised change)")
        ax.set_ylabel("gain in P(attribute)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=5, loc="best")  # manifold choices differ per attribute
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


SHIPPED_MEASURE_NET = Path(__file__).resolve().parents[1] / "weights" / "measure_net.pt"


def _measure_net(a, out, data_cls, resolution):
    from disent.edit.classifier import fit_measure_net, load_measure_net, measure_accuracy, save_measure_net

    path = Path(a.measure_net) if a.measure_net else SHIPPED_MEASURE_NET
    info_path = path.with_suffix(".json")
    if path.exists():
        return load_measure_net(path), json.loads(info_path.read_text()) if info_path.exists() else {}
    if a.measure_net:
        raise FileNotFoundError(f"--measure-net {path}: no such file")
    path, info_path = out / "measure_net.pt", out / "measure_net.json"  # none shipped: train one here

    def tensors(split, size):
        data = data_cls(split=split, resolution=resolution, seed=a.seed, size=size)
        b = get_batch(data, range(len(data)))
        return b["image"], attr_matrix(b), b["sh"], b["pose"], identity_params(data, range(len(data)))

    t0 = time.time()
    train = tensors("train", a.train_size)
    net = fit_measure_net(*train, steps=a.train_steps, seed=a.seed, log_every=250)
    info = {
        "train_size": a.train_size,
        "steps": a.train_steps,
        "seconds": round(time.time() - t0, 1),
        "val": measure_accuracy(net, *tensors("val", 500)),
    }
    save_measure_net(net, path, info)
    info_path.write_text(json.dumps(info, indent=2))
    return net, info


def figure(columns: list[torch.Tensor], titles: list[str], path: Path) -> None:
    """Columns of ``[N,3,H,W]`` images with a title each (the paper's figure layout)."""
    from disent.images import image_grid

    image_grid(list(zip(titles, columns)), path, columns=True, scale=1.3, dpi=120)


def traversal_figures(shown: dict, attribute: str, lambdas, alphas, out: Path) -> None:
    """One attribute's progression along the paper's manifold choice (``fig_<attribute>_progression.png``) and
    every manifold choice at one strength (``fig_<attribute>_manifolds.png``)."""
    paper = next(k for k in dict.fromkeys(k[0] for k in shown if isinstance(k, tuple)) if k.startswith("paper"))
    figure(
        [shown["input"], shown["recon"]]
        + [shown[(paper, "dmt", s)] for s in lambdas]
        + [shown[(paper, "barycenter", alphas[-1])], shown["truth"]],
        ["input", "recon"] + [f"λ={s:g}" for s in lambdas] + [f"bary α={alphas[-1]:g}", "truth"],
        out / f"fig_{attribute}_progression.png",
    )
    labels = list(dict.fromkeys(k[0] for k in shown if isinstance(k, tuple)))
    lam = 0.03 if 0.03 in lambdas else lambdas[len(lambdas) // 2]
    figure(
        [shown["input"], shown["recon"]] + [shown[(lb, "dmt", lam)] for lb in labels],
        ["input", "recon"] + [f"{lb} λ={lam:g}" for lb in labels],
        out / f"fig_{attribute}_manifolds.png",
    )


def relight_figure(example: dict, path: Path) -> None:
    """One face relit by each route (shading images scaled to their maximum)."""
    shade = lambda s: s / s.flatten(1).amax(1).clamp_min(1e-6)[:, None, None, None]  # noqa: E731
    figure(
        [
            example[k] if not k.startswith("S_") else shade(example[k])
            for k in ("target", "source", "S_target", "S_transfer", "transfer", "ratio", "decode", "truth")
        ],
        ["target", "source", "S target", "S transfer", "transfer", "ratio", "decode", "truth"],
        path,
    )


def summary_text(a, net_info: dict, rows: list, claims: list, rel_rows: list) -> list[str]:
    """The measurement's tables, as printed at its end (the report builds its own from edit.json)."""
    keys = [
        "attribute",
        "manifolds",
        "method",
        "strength",
        "step",
        "success",
        "gain",
        *LEAK_KEYS,
        "leakage",
        "gain_per_leak",
    ]
    rel_keys = ["method", *RELIGHT_SCORES, "lights", "faces"]
    return [
        f"# Editing measured on SynthFaces\n\nrun: `{a.run}`; pools of {a.pool_size}, {a.sources} source "
        f"faces per attribute; measuring net (held-out): `{json.dumps(net_info.get('val', {}))}`\n",
        "## Traversal\n",
        "Gains and leakage are against the unedited reconstruction (`reconstruction` rows); the reader "
        "was trained on the generator's sharp renders, so on a blurry reconstruction read the *changes*, "
        "not the absolute success. `truth` rows: the generator's own edit of the input, same reader. "
        "`step`: move along the pools' mean difference (barycenter: = alpha).\n",
        markdown_table(rows, keys),
        "\n## Success per unit leakage by manifold choice (the paper's claim: `paper:` ranks first)\n",
        markdown_table(claims, list(claims[0])),
        "\n## Relighting (PSNR dB / SSIM against the generator's render under the source light)\n",
        markdown_table(rel_rows, rel_keys) if rel_rows else "(the baseline model has no lighting code)",
    ]


def run_measurements(a) -> None:
    """``python -m disent.edit measure``: tables, JSON and figures under ``<a.out>/<name>/`` (published to
    ``reports/edit/<name>/``): ``<name>`` is the model's name for a shipped model, else
    ``<model>_seed<seed>_<steps>steps_<6 hex digits of the run folder's path>`` (two runs never share a folder);
    edit.json records the run folder, model, seed, steps and the run's setting, by which the report sets the seeds
    of one setting side by side."""
    from disent.data import LIGHT_BANK, SynthFaces
    from disent.models import load_run
    from disent.runs import Run, folder_id, setting
    from disent.storage import tool_folder

    folder = tool_folder("edit", a.out)
    figures = not getattr(a, "no_figures", False)  # --no-figures: tables and JSON only
    torch.manual_seed(a.seed)
    model, cfg = load_run(a.run)
    steps = model.trained_steps
    shipped = model.shipped
    run_folder = Path(a.run) if Path(a.run).is_dir() else Path(a.run).parent.parent  # .../checkpoints/x.pt
    tag = folder_id(run_folder)  # the run's id in the report
    background = getattr(a, "background", False)
    name = cfg.model.name if shipped else f"{cfg.model.name}_seed{cfg.seed}_{steps}steps_{tag}"
    out = folder / (name + ("_background" if background else ""))  # a diagnostic beside, not over, the main one
    out.mkdir(exist_ok=True)
    R = int(getattr(model, "resolution", 64))
    net, net_info = _measure_net(a, out, SynthFaces, R)
    print("measuring net (held-out):", json.dumps(net_info.get("val", {})), flush=True)
    read_identity = net_info.get("val", {}).get("identity_rmse_std", math.inf) < IDENTITY_READABLE
    if not read_identity:
        print(
            f"the measuring net cannot read identity (held-out RMSE >= {IDENTITY_READABLE} std): d_identity is left out"
        )
    lambdas = tuple(a.lambdas or DEFAULT_LAMBDAS)
    alphas = tuple(a.alphas or DEFAULT_ALPHAS)
    rows = []
    for attribute in a.attributes:
        t0 = time.time()
        sizes = (a.pool_size, a.sources, lambdas, alphas)
        kw = {"resolution": R, "seed": a.seed, "read_identity": read_identity, "background": background}
        r, shown = edit_table(model, net, SynthFaces, attribute, *sizes, truth_override=truth_override, **kw)
        rows += r
        print(f"{attribute}: {len(r)} rows in {time.time() - t0:.0f} s", flush=True)
        if not figures:
            continue
        traversal_figures(shown, attribute, lambdas, alphas, out)
    claims = claim_summary(rows)
    if figures:
        plot_success_vs_leakage(rows, out / "fig_success_vs_leakage.png")
    rel_rows = []
    if "L" in getattr(model, "CODE_NAMES", ()):  # a rendering model (the baseline has no light to replace)
        rel_rows, example = relight_table(model, SynthFaces, LIGHT_BANK, a.relight_faces, seed=a.seed, resolution=R)
    if rel_rows and figures:
        relight_figure(example, out / "fig_relight.png")
    (out / "edit.json").write_text(
        json.dumps(
            {
                "run": a.run if shipped else str(run_folder.resolve()),
                "model": cfg.model.name,
                "seed": cfg.seed,
                "steps": steps,
                "setting": "shipped" if shipped else setting(Run.load(run_folder), drop_model=True),
                "background": background,
                "measure_net": net_info,
                "traversal": rows,
                "claims": claims,
                "relight": rel_rows,
            },
            indent=1,
        )
    )
    text = summary_text(a, net_info, rows, claims, rel_rows)
    print("\n".join(text))
    print(f"wrote {out}; publish it with: python -m disent.report --publish {folder}")


def truth_override(attribute: str) -> dict:
    """Generator overrides that switch ``attribute`` fully on (for the ``truth`` rows)."""
    return {attribute: 1.0}
