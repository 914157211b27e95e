"""Real photos: decoding and bad input, the landmark fit, caching, and dlib end to end."""

from __future__ import annotations

import io
import os
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from disent.data.photos import pseudo_gt as pg
from disent.data.photos.pseudo_gt import PseudoGTSettings, Skip, decode_image


# ----------------------------------------------------------------------------- a bad-input corpus
def png16(a: np.ndarray) -> bytes:
    """A 16-bit PNG (gray [H,W] or RGB [H,W,3]) written by hand: PIL cannot write 16-bit RGB."""
    a = np.asarray(a, dtype=">u2")
    h, w = a.shape[:2]
    raw = b"".join(b"\x00" + a[i].tobytes() for i in range(h))

    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", w, h, 16, 2 if a.ndim == 3 else 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


def encode(img: Image.Image, fmt: str, **kw) -> bytes:
    buf = io.BytesIO()
    img.save(buf, format=fmt, **kw)
    return buf.getvalue()


def portrait(size=96, seed=0) -> np.ndarray:
    """A smooth, non-constant RGB picture (not a face: the fake detector below treats it as one)."""
    y, x = np.mgrid[0:size, 0:size] / size
    rng = np.random.default_rng(seed)
    rgb = np.stack([0.5 + 0.4 * np.sin(6 * x + rng.uniform(0, 6)), 0.3 + 0.5 * y, 0.6 - 0.3 * x * y], -1)
    return (rgb * 255).astype(np.uint8)


def bad_corpus(folder: Path) -> dict[str, tuple[Path, str]]:
    """Every bad-input case of the pipeline: name -> (file, expected), where expected is
    ``"skip:<reason>"`` or ``"use:<conversion note or ''>"``."""
    rgb = portrait()
    jpeg = encode(Image.fromarray(rgb), "JPEG", quality=90)
    cases = {
        "ok.jpg": (jpeg, "use:"),
        "zero_byte.jpg": (b"", "skip:empty file"),
        "truncated.jpg": (jpeg[: len(jpeg) // 2], "skip:truncated or corrupt"),
        "truncated.png": (encode(Image.fromarray(rgb), "PNG")[:300], "skip:truncated or corrupt"),
        "text.jpg": (b"this is a text file, not a JPEG\n" * 4, "skip:not an image"),
        "gray.png": (encode(Image.fromarray(rgb[..., 1]), "PNG"), "use:L->RGB"),
        "rgba.png": (
            encode(Image.fromarray(np.dstack([rgb, np.full(rgb.shape[:2], 128, np.uint8)])), "PNG"),
            "use:RGBA->RGB over white",
        ),
        "gray16.png": (png16(rgb[..., 1].astype(np.uint16) * 257), "use:I;16->8-bit"),
        "rgb16.png": (png16(rgb.astype(np.uint16) * 257), "use:16-bit->8-bit"),
        "cmyk.jpg": (encode(Image.fromarray(rgb).convert("CMYK"), "JPEG", quality=95), "use:CMYK->RGB"),
        "one_pixel.png": (encode(Image.new("RGB", (1, 1), (200, 100, 50)), "PNG"), "skip:too small"),
        "no_face.png": (encode(Image.new("RGB", (80, 80), (90, 90, 90)), "PNG"), "skip:no face found"),
    }
    out = {}
    for name, (data, expected) in cases.items():
        (folder / name).write_bytes(data)
        out[name] = (folder / name, expected)
    os.symlink(folder / "missing-target.jpg", folder / "unreadable.jpg")  # dangling: cannot be opened
    out["unreadable.jpg"] = (folder / "unreadable.jpg", "skip:unreadable")
    return out


# ----------------------------------------------------------------------------- decoding
def test_decode_converts_to_8bit_rgb(tmp_path):
    corpus = bad_corpus(tmp_path)
    rgb = portrait()
    for name, (path, expected) in corpus.items():
        kind, what = expected.split(":", 1)
        if kind != "use":
            continue
        out, notes = decode_image(path.read_bytes())
        assert out.dtype == np.uint8 and out.shape == rgb.shape, name
        assert (what in notes) if what else not notes, (name, notes)
    dec = lambda n: decode_image(corpus[n][0].read_bytes())[0].astype(int)  # noqa: E731
    # lossless cases reproduce the pixels exactly
    assert np.array_equal(dec("rgb16.png"), rgb)
    for n in ("gray.png", "gray16.png"):
        assert np.array_equal(dec(n), np.repeat(rgb[..., 1:2], 3, 2).astype(int)), n
    # alpha 128/255 over white: c*a + 255*(1-a)
    a = 128 / 255
    assert np.abs(dec("rgba.png") - (rgb * a + 255 * (1 - a))).max() <= 1
    # lossy CMYK JPEG: close to the original colours
    assert np.abs(dec("cmyk.jpg") - rgb).mean() < 6


def test_decode_skips_with_reasons(tmp_path):
    corpus = bad_corpus(tmp_path)
    for name, (path, expected) in corpus.items():
        kind, reason = expected.split(":", 1)
        if kind != "skip" or reason in ("no face found", "unreadable"):
            continue
        with pytest.raises(Skip) as e:
            decode_image(path.read_bytes())
        assert e.value.reason == reason, (name, e.value)


def test_decode_exif_rotation():
    rgb = portrait(64)[:, :40]  # 64 rows x 40 columns
    img = Image.fromarray(rgb)
    exif = img.getexif()
    exif[0x0112] = 6  # orientation: rotate 90 degrees clockwise to display
    out, notes = decode_image(encode(img, "PNG", exif=exif.tobytes()))
    assert out.shape == (40, 64, 3) and "EXIF rotation" in notes
    assert np.array_equal(out, np.rot90(rgb, -1))


def test_similarity_align_recovers_a_known_transform():
    rng = np.random.default_rng(0)
    src = rng.uniform(0, 100, (68, 2))
    th, s, t = 0.3, 0.4, np.array([5.0, -3.0])
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    M = pg.similarity_transform(src, src @ (s * R).T + t)
    assert np.allclose(M[:2, :2], s * R) and np.allclose(M[:2, 2], t)


# ----------------------------------------------------------------------------- the landmark fit
def known_face(seed: int, fitter, resolution=64):
    """Parameters of a random face (pose within +-25 degrees) and its projected landmarks."""
    rng = np.random.default_rng(seed)
    p = np.zeros(fitter.n_pose + fitter.n_identity + fitter.n_expression)
    p[:3] = np.radians(rng.uniform(-25, 25, 3))
    p[3], p[4:6] = np.log(0.3 * resolution), resolution / 2 + rng.normal(0, 2, 2)
    p[6 : 6 + fitter.n_identity] = rng.normal(0, 1, fitter.n_identity)
    p[-2:] = rng.uniform(0, 1, 2)
    return p, fitter.project_landmarks(p, resolution)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fit_recovers_a_known_face(seed):
    """Landmarks projected from a known face: with a weak prior the fit recovers pose and landmarks."""
    s = PseudoGTSettings(lambda_identity=1e-4, lambda_expression=1e-4)
    fitter = pg.face_model_fitter(s)
    p, lm = known_face(seed, fitter)
    fit = pg.fit_landmarks(lm, 64, s, fitter)
    q = fit["params"]
    assert fit["residual_px"] < 0.01
    assert np.abs(np.degrees(q[:3] - p[:3])).max() < 0.5
    assert np.abs(q[-2:] - p[-2:]).max() < 0.1  # smile and open
    # scale trades off against the model's size components; the posed 3-D landmarks do not
    P, Q = fitter.project(p, fitter.landmarks3d(p)), fitter.project(q, fitter.landmarks3d(q))
    assert np.abs((P - P.mean(0)) - (Q - Q.mean(0))).max() < 0.3  # pixels, depth included


def test_fit_prior_and_noise():
    """The default prior pulls coefficients to the mean (residual grows, norm shrinks);
    landmark noise of sigma px leaves a residual of the order of sigma, not more."""
    weak, strong = PseudoGTSettings(lambda_identity=1e-4), PseudoGTSettings(lambda_identity=10.0)
    fitter = pg.face_model_fitter(weak)
    p, lm = known_face(3, fitter)
    fw, fs = pg.fit_landmarks(lm, 64, weak, fitter), pg.fit_landmarks(lm, 64, strong, fitter)
    n = fitter.n_identity
    assert np.linalg.norm(fs["params"][6 : 6 + n]) < np.linalg.norm(fw["params"][6 : 6 + n])
    assert fs["residual_px"] > fw["residual_px"]
    noisy = lm + np.random.default_rng(0).normal(0, 1.0, lm.shape)
    fn = pg.fit_landmarks(noisy, 64, PseudoGTSettings(), fitter)
    assert 0.5 < fn["residual_px"] < 1.5  # 2-D noise of 1 px per axis has RMS distance sqrt(2)
    assert np.abs(np.degrees(fn["params"][:3] - p[:3])).max() < 8


def test_fit_is_invariant_to_a_similarity_of_the_photo():
    """Scaling, rotating and shifting the landmarks changes only scale, roll and shift."""
    s = PseudoGTSettings(lambda_identity=1e-4, lambda_expression=1e-4)
    fitter = pg.face_model_fitter(s)
    _, lm = known_face(4, fitter)
    th = np.radians(20)
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    a, b = pg.fit_landmarks(lm, 64, s, fitter), pg.fit_landmarks(lm @ (1.5 * R).T + [3, -2], 64, s, fitter)
    assert b["residual_px"] < 0.02
    assert abs(np.exp(b["params"][3] - a["params"][3]) - 1.5) < 0.01
    assert np.allclose(a["params"][:2], b["params"][:2], atol=np.radians(0.5))


# ----------------------------------------------------------------------------- the batch: bad input, cache
class TemplateDetector:
    """Stands in for dlib: the face model's own frontal landmarks, scaled to the photo;
    'no face' on a constant image."""

    name = "template"

    def __init__(self, settings):
        self.fitter = pg.face_model_fitter(settings)

    def __call__(self, rgb):
        if np.ptp(rgb) == 0:
            raise Skip("no face found")
        h, w = rgb.shape[:2]
        return self.fitter.template(min(h, w)) + [(w - min(h, w)) / 2, (h - min(h, w)) / 2], 1


def test_prepare_handles_every_bad_input_and_caches(tmp_path, monkeypatch):
    folder = tmp_path / "photos"
    folder.mkdir()
    corpus = bad_corpus(folder)
    s = PseudoGTSettings(resolution=32)
    files = [p for p, _ in corpus.values()]
    records, summary = pg.prepare(files, s, tmp_path / "cache", progress=False, detector=TemplateDetector(s))
    for rec, (name, (_, expected)) in zip(records, corpus.items()):
        kind, what = expected.split(":", 1)
        assert rec.used == (kind == "use"), (name, rec)
        if kind == "skip":
            assert rec.reason == what, (name, rec)
        elif what:
            assert what in rec.notes, (name, rec)
    n_used = sum(e.startswith("use") for _, e in corpus.values())
    assert summary["used"] == n_used and summary["skipped"] == len(corpus) - n_used
    assert summary["skip_reasons"]["truncated or corrupt"] == 2 and summary["skip_reasons"]["unreadable"] == 1
    arrays = pg.load_cached(records[0])
    assert arrays["image"].shape == (32, 32, 3) and arrays["normal_pseudo"].shape == (3, 32, 32)
    assert arrays["sh_pseudo"].shape == (3, 9) and np.isfinite(arrays["sh_pseudo"]).all()
    # landmarks placed exactly on the model's frontal template: the fit is (nearly) exact and frontal
    assert records[0].residual_px < 0.05 and np.abs(np.degrees(arrays["params"][:3])).max() < 1.0
    mask = arrays["mask_pseudo"][0] > 0
    assert mask.sum() > 100 and np.allclose(
        np.linalg.norm(arrays["normal_pseudo"][:, mask].astype(float), axis=0), 1, atol=2e-3
    )

    # second pass: nothing is recomputed, not even hashed; a changed file is
    monkeypatch.setattr(pg, "process", lambda *a, **k: pytest.fail("second pass recomputed a cached image"))
    again, summary2 = pg.prepare(files, s, tmp_path / "cache", progress=False, detector=TemplateDetector(s))
    assert summary2 == summary and [r.cache for r in again] == [r.cache for r in records]
    monkeypatch.undo()
    (folder / "gray.png").write_bytes((folder / "ok.jpg").read_bytes())
    os.utime(folder / "gray.png", ns=(1, 1))
    third, _ = pg.prepare(files, s, tmp_path / "cache", progress=False, detector=TemplateDetector(s))
    assert third[list(corpus).index("gray.png")].notes == []


def test_prepare_keeps_finished_work_when_interrupted(tmp_path, monkeypatch):
    """A crash in the middle of a batch loses nothing already processed."""
    folder = tmp_path / "photos"
    folder.mkdir()
    files = []
    for i in range(3):
        files.append(folder / f"{i}.png")
        files[-1].write_bytes(encode(Image.fromarray(portrait(64, seed=i)), "PNG"))
    s = PseudoGTSettings(resolution=32)
    det = TemplateDetector(s)
    real, calls = pg.process, []

    def crash_on_third(data, settings, detector=None):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(data, settings, detector)

    monkeypatch.setattr(pg, "process", crash_on_third)
    with pytest.raises(KeyboardInterrupt):
        pg.prepare(files, s, tmp_path / "cache", progress=False, detector=det)
    monkeypatch.setattr(pg, "process", real)
    calls.clear()
    monkeypatch.setattr(pg, "process", lambda *a, **k: (calls.append(1), real(*a, **k))[1])
    records, summary = pg.prepare(files, s, tmp_path / "cache", progress=False, detector=det)
    assert len(calls) == 1 and summary["used"] == 3


# ----------------------------------------------------------------------------- the data set
def celeba_folder(root: Path, n: int = 12) -> Path:
    """A miniature CelebA layout: img_align_celeba/, list_attr_celeba.txt, list_eval_partition.txt."""
    (root / "img_align_celeba").mkdir(parents=True)
    names = ["5_o_Clock_Shadow", "Eyeglasses", "No_Beard", "Smiling", "Young"]
    lines = [str(n), " ".join(names)]
    parts = []
    for i in range(n):
        f = f"{i + 1:06d}.jpg"
        Image.fromarray(portrait(80, seed=i)).save(root / "img_align_celeba" / f, quality=90)
        v = [1, 1 if i % 3 == 0 else -1, -1 if i % 4 == 0 else 1, 1 if i % 2 == 0 else -1, -1 if i % 5 == 0 else 1]
        lines.append(f + "  " + " ".join(f"{x:2d}" for x in v))
        parts.append(f"{f} {0 if i < 6 else 1 if i < 8 else 2}")
    (root / "list_attr_celeba.txt").write_text("\n".join(lines) + "\n")
    (root / "list_eval_partition.txt").write_text("\n".join(parts) + "\n")
    return root


def test_folder_faces_celeba_layout(tmp_path):
    from disent.data.photos.folder import FolderFaces

    root = celeba_folder(tmp_path / "celeba")
    kw = dict(
        resolution=32,
        cache_dir=tmp_path / "cache",
        progress=False,
        detector=TemplateDetector(PseudoGTSettings(resolution=32)),
    )
    train, val, test = (FolderFaces(root, split, **kw) for split in ("train", "val", "test"))
    assert (len(train), len(val), len(test)) == (6, 2, 4)
    item = train[1]
    assert set(item) == {"image", "normal_pseudo", "mask_pseudo", "uv_pseudo", "normal_uv_pseudo", "sh_pseudo", "attrs"}
    shapes = {k: tuple(v.shape) for k, v in item.items() if k != "attrs"}
    assert shapes == {
        "image": (3, 32, 32),
        "normal_pseudo": (3, 32, 32),
        "mask_pseudo": (1, 32, 32),
        "uv_pseudo": (2, 32, 32),
        "normal_uv_pseudo": (3, 32, 32),
        "sh_pseudo": (3, 9),
    }
    assert all(v.dtype == torch.float32 for k, v in item.items() if k != "attrs")
    assert 0 <= item["image"].min() and item["image"].max() <= 1
    # 000002.jpg: Smiling -1, No_Beard +1, Eyeglasses -1, Young +1
    assert {k: float(v) for k, v in item["attrs"].items() if not k.endswith("strength")} == {
        "smiling": 0.0,
        "beard": 0.0,
        "eyeglasses": 0.0,
        "senior": 0.0,
    }
    pool = FolderFaces(root, "pool_smiling", **kw)  # test split: 000009..000012, smiling on 9 and 11
    assert [float(pool[i]["attrs"]["smiling"]) for i in range(len(pool))] == [1, 0, 1, 0]
    with pytest.raises(ValueError, match="unknown split"):
        FolderFaces(root, "lightbank", **kw)


def test_srgb_transfer_closed_forms():
    """IEC 61966-2-1: fixed ends, the linear toe, a known mid value, a continuous knee, and an exact inverse."""
    from disent.images import linear_to_srgb, srgb_to_linear

    x = torch.linspace(0, 1, 1001, dtype=torch.float64)
    lin = srgb_to_linear(x)
    assert float(lin[0]) == 0 and float(lin[-1]) == pytest.approx(1, abs=1e-12)
    assert float(srgb_to_linear(torch.tensor(0.04, dtype=torch.float64))) == pytest.approx(0.04 / 12.92)
    assert float(srgb_to_linear(torch.tensor(0.5, dtype=torch.float64))) == pytest.approx(0.214041, abs=1e-6)
    knee = torch.tensor([0.04045 - 1e-9, 0.04045 + 1e-9], dtype=torch.float64)
    assert float(srgb_to_linear(knee).diff().abs()) < 1e-6
    assert (lin.diff() > 0).all()  # monotone: no two codes decode to one radiance
    assert torch.allclose(linear_to_srgb(lin), x, atol=1e-9)
    assert np.allclose(srgb_to_linear(x.numpy()), lin.numpy()) and isinstance(srgb_to_linear(x.numpy()), np.ndarray)


def test_on_matte_blacks_out_the_face_layers_where_the_matte_shows_the_background():
    from disent.images import on_matte

    matte = torch.tensor([[[[0.2, 0.5], [0.51, 1.0]]]])
    out = {"matte": matte, "albedo": torch.full((1, 3, 2, 2), 0.4), "recon": torch.full((1, 3, 2, 2), 0.7)}
    kept = torch.tensor([[[[0.0, 0.0], [1.0, 1.0]]]])  # over 0.5 only
    assert torch.equal(on_matte(out, "albedo"), 0.4 * kept.expand(1, 3, 2, 2))
    assert torch.equal(on_matte(out, "recon"), out["recon"])  # not a face layer: the whole picture
    assert torch.equal(on_matte({"albedo": out["albedo"]}, "albedo"), out["albedo"])  # no matte: as it is


def test_folder_items_and_their_light_are_in_linear_radiance(tmp_path):
    """An item's image is its cached 8-bit crop decoded from sRGB, and sh_pseudo is L-hat of that decoded image
    (not of the stored sRGB codes), so the models and the pseudo-GT light read the same pixels as SynthFaces'."""
    from disent.data.photos.folder import FolderFaces
    from disent.images import linear_to_srgb, srgb_to_linear
    from disent.render import fit_sh

    s = PseudoGTSettings(resolution=32)
    ds = FolderFaces(
        celeba_folder(tmp_path / "celeba"),
        "train",
        32,
        cache_dir=tmp_path / "cache",
        progress=False,
        detector=TemplateDetector(s),
    )
    item, crop = ds[0], pg.load_cached(ds.records[0])["image"]
    assert torch.allclose(item["image"], srgb_to_linear(torch.from_numpy(crop).permute(2, 0, 1).float() / 255))
    geometry = (item["normal_pseudo"][None], item["mask_pseudo"][None])
    decoded, encoded = (fit_sh(x[None], *geometry)[0] for x in (item["image"], linear_to_srgb(item["image"])))
    assert torch.allclose(item["sh_pseudo"], decoded, rtol=1e-2, atol=1e-3)
    assert not torch.allclose(item["sh_pseudo"], encoded, rtol=0.1, atol=0.01)


def test_build_passes_the_config(monkeypatch):
    from disent.data.photos import folder

    seen = {}
    monkeypatch.setattr(folder, "FolderFaces", lambda *a, **k: seen.update(args=a, kw=k))
    cfg = {
        "name": "folder",
        "root": "/photos",
        "resolution": 32,
        "seed": 3,
        "cache_dir": None,
        "workers": 2,
        "multiple_faces": "skip",
        "predictor": None,
        "train_size": None,
        "test_size": 8,
    }
    folder.build(cfg, "test", 8)
    assert seen["args"] == ("/photos",)
    assert seen["kw"] == {
        "split": "test",
        "resolution": 32,
        "seed": 3,
        "size": 8,
        "cache_dir": None,
        "workers": 2,
        "split_by": "hash",
        "multiple_faces": "skip",
    }


def test_folder_faces_plain_folder_split_is_stable(tmp_path):
    from disent.data.photos.folder import FolderFaces, hash_split

    root = tmp_path / "plain"
    (root / "sub").mkdir(parents=True)
    for i in range(20):
        Image.fromarray(portrait(48, seed=i)).save(root / ("sub" if i % 2 else "") / f"{i}.png")
    (root / "empty.png").write_bytes(b"")
    kw = dict(
        resolution=32,
        cache_dir=tmp_path / "cache",
        progress=False,
        detector=TemplateDetector(PseudoGTSettings(resolution=32)),
    )
    splits = {s: FolderFaces(root, s, **kw) for s in ("train", "val", "test")}
    assert sum(len(d) for d in splits.values()) == 20  # every photo once, the empty file skipped
    assert sum(d.summary["skip_reasons"].get("empty file", 0) for d in splits.values()) == 1
    assert "attrs" not in splits["train"][0]
    assert hash_split("sub/1.png", 0) == hash_split("sub/1.png", 0)
    assert len(FolderFaces(root, "train", size=3, **kw)) == 3
    with pytest.raises(ValueError, match="needs attribute labels"):
        FolderFaces(root, "pool_smiling", **kw)


# ----------------------------------------------------------------------------- dlib, end to end
def _dlib_settings(**kw) -> PseudoGTSettings:
    pytest.importorskip("dlib")
    try:
        pg.default_predictor_path()
    except FileNotFoundError as e:
        pytest.skip(str(e))
    return PseudoGTSettings(**kw)


def test_end_to_end_on_bundled_photos(tmp_path):
    """dlib + fit + rendering on the real photos bundled with scikit-image and matplotlib,
    with the bad-input cases that need a detector: no face, several faces."""
    from disent.data.photos.study import bundled_photos

    s = _dlib_settings()
    photos = bundled_photos(tmp_path / "photos")
    astro = Image.open(photos["astronaut"][0]).reduce(2)
    grace = Image.open(photos["grace_hopper"][0]).convert("RGB").reduce(2)
    two = Image.new("RGB", (512, 300))
    two.paste(astro, (0, 0))
    two.paste(grace, (256, 0))  # the astronaut's face is the smaller one
    two.save(tmp_path / "two_faces.png")
    files = (
        photos["astronaut"]
        + photos["grace_hopper"]
        + photos["lfw_faces"][:6]
        + photos["lfw_nonfaces"][:3]
        + [tmp_path / "two_faces.png"]
    )
    records, summary = pg.prepare(files, s, tmp_path / "cache", progress=False)
    by_name = {Path(r.path).stem: r for r in records}
    assert by_name["astronaut"].used and by_name["grace_hopper"].used
    assert sum(by_name[f"lfw_{i:03d}"].used for i in range(6)) >= 3  # 25x25 faces: most are found
    assert all(by_name[f"lfw_{i:03d}"].reason == "no face found" for i in range(100, 103))
    two_rec = by_name["two_faces"]
    assert two_rec.used and any(
        " faces (detection scores " in n and n.endswith("kept the largest") for n in two_rec.notes
    ), two_rec.notes

    # the kept face is Grace Hopper's (right half): its landmarks, mapped back to the photo, match hers
    def photo_landmarks(rec):
        z = pg.load_cached(rec)
        M = np.linalg.inv(z["align"].astype(float))
        return z["landmarks"] @ M[:2, :2].T + M[:2, 2]

    shift = photo_landmarks(two_rec).mean(0) - photo_landmarks(by_name["grace_hopper"]).mean(0) / 2
    assert np.abs(shift - [256, 0]).max() < 4  # pixels of the 512x300 composite
    for name in ("astronaut", "grace_hopper"):
        z = pg.load_cached(by_name[name])
        mask = z["mask_pseudo"][0] > 0
        assert 300 < mask.sum() < 0.6 * 64 * 64  # the face region of a 64 px crop
        assert np.allclose(np.linalg.norm(z["normal_pseudo"][:, mask].astype(float), axis=0), 1, atol=2e-3)
        assert (z["normal_pseudo"][2][mask] > 0).mean() > 0.99  # visible surface faces the camera
        assert by_name[name].residual_px < 4.0  # RMS landmark error, 64 px crop
    skip = pg.prepare(
        [tmp_path / "two_faces.png"], _dlib_settings(multiple_faces="skip"), tmp_path / "cache", progress=False
    )[0][0]
    assert not skip.used and skip.reason == "several faces"
    faces = pg.load_cached(two_rec)["faces"]  # [left, top, right, bottom, score], largest first
    assert faces.shape[0] >= 2 and faces.shape[1] == 5  # (a third, weak detection may come with them)
    assert faces[0, 0] > 256 > faces[1, 2]  # Grace Hopper on the right, the astronaut on the left
    second = pg.prepare([tmp_path / "two_faces.png"], _dlib_settings(face=1), tmp_path / "cache", progress=False)[0][0]
    assert second.used and "kept face 1 by size" in " ".join(second.notes)
    assert photo_landmarks(second).mean(0)[0] < 256  # the astronaut's landmarks
    third = pg.prepare(
        [tmp_path / "two_faces.png"], _dlib_settings(face=len(faces)), tmp_path / "cache", progress=False
    )[0][0]
    assert not third.used and third.reason == "no such face"


@pytest.mark.slow
def test_worker_processes_match_in_process(tmp_path):
    from disent.data.photos.study import bundled_photos

    s = _dlib_settings()
    files = bundled_photos(tmp_path / "photos")["lfw_faces"][:6]
    one, _ = pg.prepare(files, s, tmp_path / "c1", progress=False)
    two, _ = pg.prepare(files, s, tmp_path / "c2", workers=2, progress=False)
    for a, b in zip(one, two):
        assert a.used == b.used and a.reason == b.reason
        if a.used:
            za, zb = pg.load_cached(a), pg.load_cached(b)
            assert all(np.array_equal(za[k], zb[k]) for k in ("image", "normal_pseudo", "mask_pseudo", "sh_pseudo"))


def test_pipeline_on_synthfaces_with_exact_landmarks():
    """SynthFaces renders with their exact model landmarks: align + fit recovers yaw and pitch
    (roll is removed by the alignment), so camera and pose conventions agree with the renderer."""
    from disent.data import SynthFaces

    ds, s = SynthFaces("test", 64, size=8), PseudoGTSettings()
    fitter = pg.face_model_fitter(s)
    scene, batch = ds.params(range(8)), ds.get_batch(range(8))
    landmarks = fitter.synth_landmarks(scene, 64)
    err = []
    for i in range(8):
        img = (batch["image"][i].permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
        out = pg.pseudo_gt_from_landmarks(img, landmarks[i], s)
        assert out["residual_px"] < 1.0  # only senior shape and identity beyond 4 components are unmodelled
        err.append(np.degrees(out["params"][:2]) - scene["pose"][i, :2].numpy())
        # The alignment turns the image by theta (pixel frame, y down); roll is the last rotation
        # (R = R_roll R_pitch R_yaw), so the crop's roll is exactly the scene's minus theta.
        theta = np.degrees(np.arctan2(out["align"][1, 0], out["align"][0, 0]))
        assert abs(np.degrees(out["params"][2]) - (scene["pose"][i, 2].item() - theta)) < 1.0
    assert np.abs(err).mean() < 2.0, err


def test_fitter_camera_matches_the_rasterizer():
    """The fit's pixel projection and disent.data.synth.raster.to_camera agree on every landmark."""
    import torch

    from disent.data.synth.raster import to_camera

    fitter = pg.face_model_fitter(PseudoGTSettings())
    p, lm = known_face(5, fitter, resolution=128)
    cam = fitter.to_raster(p, 128)
    K = fitter.n_identity
    verts = fitter.model.shape(torch.tensor(p[None, 6 : 6 + K]), torch.tensor(p[None, 6 + K :])).double()
    xy = to_camera(
        verts[:, fitter.model.landmarks],
        torch.tensor(cam["pose"][None]),
        torch.tensor([cam["scale"]]),
        torch.tensor(cam["shift"][None]),
    )[0, :, :2].numpy()
    assert np.allclose(fitter.raster_to_pixels(xy, 128), lm, atol=1e-6)
    back = fitter.from_raster(cam["pose"], cam["scale"], cam["shift"], 128)
    assert np.allclose(back[:6], p[:6])


def test_align_is_consistent_across_photo_sizes():
    """A photo and the same photo 16x larger (each pixel a 16x16 block; pixel centres map as
    x -> 16 x + 7.5) give the same crop: the box-reduction path keeps the coordinates."""
    rng = np.random.default_rng(1)
    small = portrait(96, seed=3)
    template = rng.uniform(8, 24, (68, 2))
    landmarks = 2.0 * template + 10.0  # crop scale 0.5: the small photo is blurred, the big one reduced
    big = np.kron(small, np.ones((16, 16, 1), np.uint8))
    a, la, _ = pg.align(small, landmarks, template, 32)
    b, lb, _ = pg.align(big, 16 * landmarks + 7.5, template, 32)
    assert np.allclose(la, lb) and np.allclose(la, template)
    assert np.abs(a.astype(int) - b).max() <= 1


def photo_records_and_model(tmp_path):
    from disent.models import build_model

    folder = tmp_path / "photos"
    folder.mkdir()
    for i in range(3):
        Image.fromarray(portrait(64, seed=i)).save(folder / f"{i}.png")
    s = PseudoGTSettings(resolution=32)
    records, _ = pg.prepare(
        sorted(folder.iterdir()), s, tmp_path / "cache", progress=False, detector=TemplateDetector(s)
    )
    torch.manual_seed(0)
    return records, build_model({"name": "explicit", "resolution": 32, "code_dim": 16, "matting": True}).eval()


def test_domain_gap_numbers_on_photo_records(tmp_path):
    from disent.eval.photos import gap_metrics, photo_batch

    records, model = photo_records_and_model(tmp_path)
    batch = photo_batch(records)
    assert batch["image"].shape == (3, 3, 32, 32) and batch["sh_pseudo"].shape == (3, 3, 9)
    gap = gap_metrics(model, batch)
    assert gap["n"] == 3 and all(np.isfinite(v) for v in gap.values())
    assert 0 <= gap["matte_iou_mask_pseudo"] <= gap["matte_covers_mask_pseudo"] <= 1
    # the constants beside it: a mean map that is the first photo's pseudo normals scores 0 on that photo
    one = {k: v[:1] for k, v in batch.items()}
    trivial = {"normal": batch["normal_pseudo"][0], "sh_pseudo": batch["sh_pseudo"][0]}
    gap = gap_metrics(model, one, trivial)
    assert gap["trivial_normal_vs_pseudo_deg"] == pytest.approx(0, abs=0.1)
    assert gap["trivial_sh_vs_pseudo_mse"] == pytest.approx(0, abs=1e-6)
    assert gap["trivial_light_vs_pseudo_shading_si_mse"] == pytest.approx(0, abs=1e-9)
    # the light on the face ignores what the face hides: L-hat's coefficients moved along a direction whose shading
    # over the face vanishes score the same shading, however far the coefficients moved
    from disent.eval.metrics import sh_gram

    gram = sh_gram(one["normal_pseudo"].double(), one["mask_pseudo"] > 0.5)[0]
    hidden = torch.linalg.eigh(gram).eigenvectors[:, 0].float()  # the direction the face shows least
    moved = {"normal": trivial["normal"], "sh_pseudo": trivial["sh_pseudo"] + 5 * hidden}
    gap = gap_metrics(model, one, moved)
    assert gap["trivial_sh_vs_pseudo_mse"] > 0.5  # 1: orthogonal to L-hat's coefficients
    assert gap["trivial_light_vs_pseudo_shading_si_mse"] < 1e-2 * gap["trivial_sh_vs_pseudo_mse"]


def test_grayscale_and_zoom_of_a_photo_batch(tmp_path):
    from disent.eval.photos import grayscale, photo_batch, zoomed

    records, _ = photo_records_and_model(tmp_path)
    batch = photo_batch(records)
    gray = grayscale(batch["image"])
    assert torch.equal(gray[:, 0], gray[:, 1]) and torch.equal(gray[:, 1], gray[:, 2])
    white = grayscale(torch.ones(1, 3, 2, 2))
    assert torch.allclose(white, torch.ones_like(white))  # the luma weights sum to 1
    same = zoomed(batch, 1.0)  # x1 is the identity
    for k in ("image", "normal_pseudo", "mask_pseudo"):
        on = batch["mask_pseudo"][:, 0] > 0.5 if k == "normal_pseudo" else slice(None)
        a, b = (x.movedim(1, -1)[on] if k == "normal_pseudo" else x for x in (same[k], batch[k]))
        assert torch.allclose(a, b, atol=1e-3), k  # the cached normals are stored at reduced precision
    twice = zoomed(batch, 2.0)  # the mask's area grows with the square of the zoom, less what leaves the crop
    ratio = twice["mask_pseudo"].sum() / batch["mask_pseudo"].sum()
    assert 2.5 < ratio <= 4.05
    assert torch.allclose(twice["normal_pseudo"].norm(dim=1)[twice["mask_pseudo"][:, 0] > 0.5], torch.tensor(1.0))


def test_colour_match_gives_each_face_the_target_statistics():
    """Inside ``mask_pseudo`` each channel gets the target mean and std (no clamping where the target sits well
    inside [0, 1]); a batch already at the target is left as it is; pixels outside move with the same map."""
    from disent.eval.photos import colour_matched, face_colour

    g = torch.Generator().manual_seed(0)
    mask = torch.zeros(2, 1, 16, 16)
    mask[:, :, 4:12, 3:13] = 1
    image = 0.3 + 0.2 * torch.rand(2, 3, 16, 16, generator=g)
    image[1] = image[1] * torch.tensor([0.5, 1.0, 0.7])[:, None, None]  # a different colour cast per photo
    batch = {"image": image, "mask_pseudo": mask}
    target = (torch.tensor([0.55, 0.45, 0.40]), torch.tensor([0.05, 0.04, 0.03]))
    matched = colour_matched(batch, target)
    mean, std = face_colour(matched)
    assert torch.allclose(mean, target[0].expand(2, 3), atol=1e-5) and torch.allclose(std, target[1].expand(2, 3))
    again = colour_matched(matched, target)
    assert torch.allclose(again["image"], matched["image"], atol=1e-5)
    m0, s0 = face_colour(batch)
    corner = (image[:, :, 0, 0] - m0) * target[1] / s0 + target[0]  # outside the mask: the same affine map
    assert torch.allclose(matched["image"][:, :, 0, 0], corner.clamp(0, 1), atol=1e-5)


@pytest.mark.slow
def test_photo_figures(tmp_path):
    from disent.eval.photos import figures, photo_batch

    records, model = photo_records_and_model(tmp_path)
    figures(model, photo_batch(records), ["a", "b", "c"], tmp_path, "untrained")
    assert (tmp_path / "decomposition_untrained.png").is_file() and (tmp_path / "relight_untrained.png").is_file()


def test_folder_config_lists_every_setting():
    from omegaconf import OmegaConf

    cfg = OmegaConf.load(Path(__file__).parents[1] / "conf" / "data" / "folder.yaml")
    dataset_keys = {"name", "root", "resolution", "train_size", "test_size", "seed", "split_by", "cache_dir", "workers"}
    assert set(cfg) - dataset_keys == set(PseudoGTSettings.__dataclass_fields__) - {"resolution"}
    assert cfg.name == "folder" and OmegaConf.is_missing(cfg, "root")


def test_anatomy_reads_what_the_colour_match_closes():
    from disent.report.tools import anatomy_table

    def m(deg):
        return {"normal_vs_pseudo_deg": deg, "trivial_normal_vs_pseudo_deg": 16.7}

    gap = {
        "model": "explicit",
        "tag": "explicit_shipped",
        "photos": m(16.0),
        "synthfaces_test": m(8.0),
        "anatomy": {
            "synthfaces_test_grayscale": m(8.3),
            "photos_zoom": {"1": m(16.0)},
            "photos_colour_matched": m(14.0),
        },
    }
    lines = anatomy_table([gap])  # a result written before the photos were decoded: no sRGB column
    assert "| explicit (explicit_shipped) | 8.00 | 8.30 | – | 16.00 | 14.00 | 16.70 |" in lines
    assert any("matching the face's colour statistics closes 2.00" in line for line in lines)
    assert not any("as stored" in line for line in lines if line.startswith("- "))
    gap["anatomy"]["photos_srgb"] = m(17.5)
    lines = anatomy_table([gap])
    assert "| explicit (explicit_shipped) | 8.00 | 8.30 | 17.50 | 16.00 | 14.00 | 16.70 |" in lines
    assert any("the gap is 8.00 deg (1.50 less than on the photos as stored" in line for line in lines)
    del gap["anatomy"]["photos_colour_matched"]  # a result written before the colour match
    assert "| explicit (explicit_shipped) | 8.00 | 8.30 | 17.50 | 16.00 | – | – |" in anatomy_table([gap])


def test_gap_table_marks_results_read_from_srgb_codes():
    """A domain-gap result written before the photos were decoded says so in its domain cell; today's does not."""
    from disent.report.tools import gap_table

    m = {"n": 4, "recon_psnr": 22.0, "normal_vs_pseudo_deg": 15.0, "trivial_normal_vs_pseudo_deg": 16.7}
    old = {"model": "explicit", "tag": "old", "training": {"steps": 10}, "photos": m, "synthfaces_test": m}
    new = {**old, "tag": "new", "photo_pixels": "linear"}
    rows = [line for line in gap_table([old, new]) if line.startswith("| explicit")]
    assert [r.split(" | ")[2] for r in rows] == [
        "photos, sRGB codes (written before decoding)",
        "SynthFaces test",
        "photos",
        "SynthFaces test",
    ]
    assert all("15.00 | 16.70" in r for r in rows)
