"""Your own photos: ``python -m disent.photos`` on a folder with bad entries, the editing commands' loader
(aligned crops, EXIF, .ppm, bad entries), small folders, and no orphaned pipeline workers."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image
from test_folder import TemplateDetector, portrait

from disent.data.photos import pseudo_gt as pg
from disent.data.photos.pseudo_gt import PseudoGTSettings
from disent.images import srgb_to_linear


def photo_folder(root: Path) -> dict[str, str]:
    """Good and bad entries: name -> expected ('use' or the skip reason; 'absent': not listed at all)."""
    root.mkdir(parents=True)
    rgb = portrait(96)
    Image.fromarray(rgb).save(root / "plain.png")
    Image.fromarray(rgb).save(root / "netpbm.ppm")
    Image.fromarray(rgb[..., 0]).save(root / "gray.png")
    exif = Image.Exif()
    exif[0x0112] = 6  # the viewer turns the stored pixels 90 degrees clockwise
    Image.fromarray(rgb).transpose(Image.ROTATE_90).save(root / "rotated.jpg", exif=exif, quality=95)
    (root / "text.jpg").write_text("not an image\n")
    (root / "dangling.jpg").symlink_to(root / "gone.jpg")
    (root / "folder.jpg").mkdir()
    return {
        "plain": "use",
        "netpbm": "use",
        "gray": "use",
        "rotated": "use",
        "text": "not an image",
        "dangling": "unreadable",
        "folder": "absent",
    }


@pytest.fixture
def template_dlib(monkeypatch):
    """The pipeline's detector replaced by the template detector (dlib is an optional extra)."""
    monkeypatch.setattr(pg, "landmark_detector", lambda settings: TemplateDetector(settings))


def test_photos_command_on_a_folder_with_bad_entries(tmp_path, template_dlib, capsys):
    from disent.photos import main

    expected = photo_folder(tmp_path / "in")
    out = tmp_path / "out"
    main([str(tmp_path / "in"), "--out", str(out), "--cache-dir", str(tmp_path / "cache")])
    summary = json.loads((out / "summary.json").read_text())
    by_name = {Path(p["path"]).stem: p for p in summary["photos"]}
    for name, want in expected.items():
        if want == "absent":
            assert name not in by_name
        elif want == "use":
            assert by_name[name]["used"], by_name[name]
            folder = out / by_name[name]["folder"]
            for f in (
                "crop.png",
                "normal_pseudo.png",
                "mask_pseudo.png",
                "recon.png",
                "albedo.png",
                "normal.png",
                "shading.png",
                "matte.png",
                "relit_top.png",
                "landmarks.json",
            ):
                assert (folder / f).is_file(), (name, f)
        else:
            assert not by_name[name]["used"] and by_name[name]["reason"] == want
    assert "EXIF rotation" in by_name["rotated"]["notes"] and "L->RGB" in by_name["gray"]["notes"]
    assert (out / "decomposition.png").is_file() and (out / "relight.png").is_file()
    text = capsys.readouterr().out
    assert "skipped" in text and str(tmp_path / "in" / "dangling.jpg") in text  # the link's own name


def test_photos_command_colour_matches_each_face(tmp_path, template_dlib, monkeypatch):
    """``--colour-match``: each saved crop's face (its mask_pseudo) carries the target's colour statistics."""
    from PIL import Image

    from disent.eval import photos
    from disent.photos import main

    def png(path):  # [1, C, H, W] in [0, 1], linear: the tool writes its colour pictures sRGB-encoded
        x = torch.from_numpy(np.asarray(Image.open(path).convert("RGB"), dtype=np.float32) / 255)
        return srgb_to_linear(x.permute(2, 0, 1)[None])

    target = (torch.tensor([0.6, 0.45, 0.35]), torch.tensor([0.08, 0.06, 0.05]))
    monkeypatch.setattr(photos, "colour_target", lambda resolution: target)
    photo_folder(tmp_path / "in")
    out = tmp_path / "out"
    main(
        [
            str(tmp_path / "in" / "plain.png"),
            "--out",
            str(out),
            "--cache-dir",
            str(tmp_path / "cache"),
            "--colour-match",
        ]
    )
    summary = json.loads((out / "summary.json").read_text())
    (photo,) = summary["photos"]
    assert summary["colour_match"] and photo["used"]
    crop, mask = (png(out / photo["folder"] / f) for f in ("crop.png", "mask_pseudo.png"))
    mask = mask[:, :1]
    mean, std = photos.face_colour({"image": crop, "mask_pseudo": mask})
    assert torch.allclose(mean[0], target[0], atol=0.02) and torch.allclose(std[0], target[1], atol=0.02)


class TwoFaces(TemplateDetector):
    """Two detections, both at the template (scores 0.9 and 0.4): the choice of face is bookkeeping here."""

    def __call__(self, rgb):
        landmarks, _ = super().__call__(rgb)
        return landmarks, [
            {"score": 0.9, "box": [0, 0, 60, 60], "upsample": 1},
            {"score": 0.4, "box": [60, 0, 90, 30], "upsample": 2},
        ]


def test_photos_command_reports_and_chooses_faces(tmp_path, monkeypatch):
    from disent.photos import main

    monkeypatch.setattr(pg, "landmark_detector", lambda settings: TwoFaces(settings))
    photo_folder(tmp_path / "in")
    args = [str(tmp_path / "in" / "plain.png"), "--cache-dir", str(tmp_path / "cache")]
    main([*args, "--out", str(tmp_path / "all"), "--faces", "all"])
    photos = json.loads((tmp_path / "all" / "summary.json").read_text())["photos"]
    assert [(p["folder"], p["face"]) for p in photos] == [("000_plain", 0), ("001_plain_face1", 1)]
    assert photos[0]["notes"] == ["2 faces (detection scores 0.90, 0.40, largest first): kept the largest"]
    assert photos[1]["notes"][0].endswith("kept face 1 by size")
    assert [f["score"] for f in photos[0]["faces_found"]] == [0.9, 0.4]
    with pytest.raises(SystemExit):  # the only photo skipped: nothing decomposed, exit status 1
        main([*args, "--out", str(tmp_path / "skip"), "--faces", "skip"])
    skipped = json.loads((tmp_path / "skip" / "summary.json").read_text())["photos"]
    assert skipped[0]["reason"] == "several faces"
    with pytest.raises(SystemExit):
        main([*args, "--faces", "most"])


def test_landmarks_are_stored_in_the_photos_pixels(tmp_path, template_dlib):
    from disent.photos import main

    photo_folder(tmp_path / "in")
    out = tmp_path / "out"
    main([str(tmp_path / "in" / "plain.png"), "--out", str(out), "--cache-dir", str(tmp_path / "cache")])
    lm = json.loads(next(out.glob("000_plain/landmarks.json")).read_text())
    expected = TemplateDetector(PseudoGTSettings())(portrait(96))[0]  # what the detector saw, photo pixels
    assert np.allclose(lm["photo_xy"], expected, atol=0.02)
    assert np.ptp(np.array(lm["crop_xy"])[:, 0]) < 64 < np.ptp(np.array(lm["photo_xy"])[:, 0]) + 64


def test_photos_command_errors_are_one_line(tmp_path, capsys):
    from disent.photos import main

    with pytest.raises(SystemExit, match="does not exist"):
        main([str(tmp_path / "nothere")])
    (tmp_path / "empty").mkdir()
    with pytest.raises(SystemExit, match="no image files"):
        main([str(tmp_path / "empty")])
    with pytest.raises(SystemExit, match="no image files"):  # the inputs are checked before the model loads
        main([str(tmp_path / "empty"), "--run", "explicitt"])
    photo_folder(tmp_path / "in")
    with pytest.raises(SystemExit, match="shipped models: baseline, explicit, implicit"):
        main([str(tmp_path / "in"), "--run", "explicitt"])


def test_edit_loader_honours_exif_reads_ppm_and_skips_bad_entries(tmp_path, capsys):
    from disent.edit.__main__ import load_image, load_inputs

    photo_folder(tmp_path / "in")
    plain = load_image(tmp_path / "in" / "plain.png", 64, align=False)
    assert torch.equal(load_image(tmp_path / "in" / "netpbm.ppm", 64, align=False), plain)
    rotated = load_image(tmp_path / "in" / "rotated.jpg", 64, align=False)
    assert (rotated - plain).abs().mean() < 0.02  # upright, as a viewer shows it (JPEG noise only)
    turned = torch.rot90(plain, 1, (1, 2))
    assert (turned - plain).abs().mean() > 5 * (rotated - plain).abs().mean()
    inputs = load_inputs([str(tmp_path / "in")], 64, align=False)
    assert sorted(x.name for x in inputs) == ["gray", "netpbm", "plain", "rotated"]
    assert {x.kind for x in inputs} == {"srgb"}  # photos: their pictures are written back sRGB-encoded
    out = capsys.readouterr().out
    assert "skipped" in out and "text.jpg: not an image" in out and "dangling.jpg: unreadable" in out
    with pytest.raises(SystemExit, match=r"^error: .*text.jpg: not an image"):
        load_inputs([str(tmp_path / "in" / "text.jpg")], 64, align=False)
    with pytest.raises(SystemExit, match="neither an image, a folder"):
        load_inputs([str(tmp_path / "nothere.png")], 64)


def test_edit_aligns_faces_as_the_photo_pipeline_does(tmp_path, template_dlib):
    pytest.importorskip("dlib")  # load_inputs only aligns where dlib is installed
    from disent.edit.__main__ import load_inputs

    photo_folder(tmp_path / "in")
    ((name, x, _),) = load_inputs([str(tmp_path / "in" / "plain.png")], 64)
    crop, _ = pg.aligned_crop(tmp_path / "in" / "plain.png", PseudoGTSettings(resolution=64))
    assert torch.equal(x, torch.from_numpy(pg.crop_pixels(crop)))  # decoded from sRGB, as the pipeline reads it


def test_edit_colour_match_gives_the_face_synthfaces_colours(tmp_path, template_dlib, monkeypatch):
    """``--colour-match``: the photo's face (its pseudo-GT mask) gets the target's colour statistics; the crop is the
    aligned one, mapped per channel; without alignment it is refused."""
    pytest.importorskip("dlib")  # load_inputs only aligns where dlib is installed
    from disent.edit.__main__ import load_inputs
    from disent.eval import photos

    target = (torch.tensor([0.6, 0.45, 0.35]), torch.tensor([0.08, 0.06, 0.05]))
    monkeypatch.setattr(photos, "colour_target", lambda resolution: target)  # no SynthFaces rendering here
    photo_folder(tmp_path / "in")
    path = tmp_path / "in" / "plain.png"
    ((name, x, _),) = load_inputs([str(path)], 64, colour_match=True)
    maps = pg.process(path.read_bytes(), PseudoGTSettings(resolution=64))
    mask = torch.from_numpy(maps["mask_pseudo"].astype("float32")).reshape(1, 1, 64, 64)
    mean, std = photos.face_colour({"image": x[None], "mask_pseudo": mask})
    assert torch.allclose(mean[0], target[0], atol=0.02) and torch.allclose(std[0], target[1], atol=0.02)
    crop, _ = pg.aligned_crop(path, PseudoGTSettings(resolution=64))
    plain = torch.from_numpy(pg.crop_pixels(crop))
    inside = (mask[0, 0] > 0.5) & (x > 0.01).all(0) & (x < 0.99).all(0)  # unclamped face pixels
    for c in range(3):  # one affine map per channel: the matched pixels are a line of the aligned crop's
        a, b = plain[c][inside], x[c][inside]
        assert torch.corrcoef(torch.stack([a, b]))[0, 1] > 0.999
    with pytest.raises(SystemExit, match="--colour-match needs the face aligned"):
        load_inputs([str(path)], 64, align=False, colour_match=True)


def test_traverse_checks_the_manifolds_against_the_model():
    from disent.edit.__main__ import main

    with pytest.raises(
        SystemExit, match="--manifolds Ai: not a code of this explicit model; its codes are bg, m, L, Ne, Ae"
    ):
        main(["traverse", "explicit", "synth:0", "--attribute", "smiling", "--manifolds", "Ai"])


def test_small_folder_trains_with_split_by_all(tmp_path):
    from disent.data.photos.folder import FolderFaces

    photo_folder(tmp_path / "in")
    kw = dict(
        resolution=32,
        cache_dir=tmp_path / "cache",
        progress=False,
        detector=TemplateDetector(PseudoGTSettings(resolution=32)),
    )
    train, test = (
        FolderFaces(tmp_path / "in", "train", split_by="all", **kw),
        FolderFaces(tmp_path / "in", "test", split_by="all", **kw),
    )
    assert len(train) == len(test) == 4
    with pytest.raises(ValueError, match="split_by='random'; choose from hash, all"):
        FolderFaces(tmp_path / "in", "train", split_by="random", **kw)


WORKER_PARENT = """
import os, sys, time
from concurrent.futures import ProcessPoolExecutor
import multiprocessing as mp
from disent.data.photos.pseudo_gt import _init_worker
with ProcessPoolExecutor(1, mp_context=mp.get_context("spawn"), initializer=_init_worker) as pool:
    print(pool.submit(os.getpid).result(), flush=True)
    time.sleep(60)
"""


def _running(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    return "\nState:\tZ" not in state  # a zombie has exited


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads /proc")
def test_pipeline_workers_exit_when_their_parent_is_killed():
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    parent = subprocess.Popen([sys.executable, "-c", WORKER_PARENT], stdout=subprocess.PIPE, text=True, env=env)
    worker = int(parent.stdout.readline())
    assert _running(worker)
    parent.send_signal(signal.SIGKILL)
    parent.wait()
    deadline = time.time() + 10
    while _running(worker) and time.time() < deadline:
        time.sleep(0.1)
    assert not _running(worker)
