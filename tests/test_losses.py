"""Every loss term of Sec. 4.2 (disent/losses.py) on a closed form: a constant, a ramp or a known offset whose value
the term's formula gives by hand, plus the gradients of the terms the paper defines by formula (BWS, the
smoothness priors, E_recon-L) against central finite differences."""

import pytest
import torch
import torch.nn.functional as F

from disent import losses as L
from disent.models import Discriminator
from disent.render import C4, sh_shading
from tests.test_models import R, fake_batch


def test_discriminator_energy_and_margin_loss():
    D = Discriminator(R)
    x = torch.rand(3, 3, R, R)
    torch.testing.assert_close(D.energy(x), (D(x) - x).pow(2).mean((1, 2, 3)))
    real, fake = torch.tensor([0.1, 0.3], requires_grad=True), torch.tensor([0.5, 2.5], requires_grad=True)
    loss = L.discriminator_loss(real, fake, margin=1.0)
    assert loss.item() == pytest.approx(0.2 + (0.5 + 0) / 2)
    assert torch.autograd.grad(loss, fake)[0].tolist() == [-0.5, 0.0]
    # every generated image past the margin: the same value and a zero gradient, and the
    # generated batch is out of the graph (its backward pass is skipped)
    loss = L.discriminator_loss(real, fake, margin=0.5)
    assert loss.item() == pytest.approx(0.2) and torch.autograd.grad(loss, fake, allow_unused=True)[0] is None


def test_loss_terms_closed_forms():
    b = fake_batch()
    mask = b["mask_pseudo"]
    const = {"albedo": torch.full((4, 3, R, R), 0.3), "shading": torch.full((4, 3, R, R), 0.75)}
    assert L.smooth_A(const, b).item() == 0 and L.smooth_S(const, b).item() == 0
    assert L.BWS(const, b, c=0.75).item() == pytest.approx(0, abs=1e-12)
    assert L.BWS(const, b, c=0.5).item() == pytest.approx(0.25**2)
    # BWS is a per-channel batch mean over the face: changes outside the mask do not count
    assert L.BWS({"shading": const["shading"] + 5 * (1 - mask)}, b).item() == pytest.approx(0, abs=1e-12)
    ramp = torch.linspace(0, 1, R).expand(4, 3, R, R)  # x-gradient 1/(R-1), no y-gradient
    assert L.smooth_A({"albedo": ramp}, b).item() == pytest.approx(1 / (R - 1), rel=1e-5)
    assert L.smooth_S({"shading": ramp}, b).item() == pytest.approx(1 / (R - 1) ** 2, rel=1e-5)
    out = {"normal": b["normal_pseudo"] + 0.1 * mask, "matte": mask, "recon": b["image"], "sh": b["sh_pseudo"] + 0.5}
    assert L.recon_N(out, b).item() == pytest.approx(0.01, rel=1e-5)  # only masked pixels count
    assert L.M(out, b).item() == 0 and L.recon(out, b).item() == 0
    off = {"recon": b["image"] + 0.1 - 0.2 * mask}  # |error| 0.1 everywhere: L2 gives 0.01, L1 0.1
    assert L.recon(off, b).item() == pytest.approx(0.01, rel=1e-5)
    assert L.recon(off, b, p=1).item() == pytest.approx(0.1, rel=1e-5)
    assert L.generator_losses(off, b, {"recon": 1}, recon_p=1)["recon"].item() == pytest.approx(0.1, rel=1e-5)
    # the masked reconstruction: only the pseudo mask counts; p=2 squares the error, p=1 takes |error|
    fg = {"foreground": b["image"] + 0.1 * mask + 3 * (1 - mask)}
    assert L.recon_fg(fg, b).item() == pytest.approx(0.01, rel=1e-5)
    assert L.generator_losses(fg, b, {"recon_fg": 1}, recon_fg_p=1)["recon_fg"].item() == pytest.approx(0.1, rel=1e-5)
    # the matte: a matte of 0.75 where M-hat is 1 costs 0.0625 under L2, 0.25 under L1, over every pixel
    soft = {"matte": mask - 0.25 * mask}
    share = mask.mean().item()
    assert L.M(soft, b).item() == pytest.approx(0.0625 * share, rel=1e-5)
    assert L.generator_losses(soft, b, {"M": 1}, matte_p=1)["M"].item() == pytest.approx(0.25 * share, rel=1e-5)
    assert L.recon_L(out, b, c=None, space="coefficients").item() == pytest.approx(0.25)
    # in shading space: 0.5 more on L1 alone shades every face pixel C4 * 0.5 brighter
    lift = {"sh": b["sh_pseudo"] + 0.5 * F.one_hot(torch.tensor(0), 9)}
    assert L.recon_L(lift, b, c=None).item() == pytest.approx((C4 * 0.5) ** 2, rel=1e-5)
    # with c, L-hat's unknown constant albedo is fixed by BWS: per-channel rescaling of L-hat changes nothing,
    # and the target is the L-hat whose shading has batch mean c on the face
    rescaled = {**b, "sh_pseudo": b["sh_pseudo"] * torch.tensor([2.0, 3.0, 0.5])[None, :, None]}
    assert L.recon_L(out, rescaled).item() == pytest.approx(L.recon_L(out, b).item(), rel=1e-5)
    s_hat = sh_shading(b["normal_pseudo"], b["sh_pseudo"]) * mask
    white = b["sh_pseudo"] * (0.75 / (s_hat.sum((0, 2, 3)) / mask.sum()))[None, :, None]
    assert L.recon_L({"sh": white}, b, c=0.75).item() == pytest.approx(0, abs=1e-10)
    # gray: each face's own colour on L-hat (a skin tone left in the light, brightness kept) changes nothing, and
    # the gray target's shading has one mean over each face for the three channels
    face_mean = (s_hat.sum((2, 3)) / mask.sum((2, 3)))[:, :, None]  # [B, C, 1]: L-hat's shading mean per face
    tint = 0.5 + torch.rand(len(mask), 3, 1, generator=torch.Generator().manual_seed(1))
    tint = tint * face_mean.mean(1, keepdim=True) / (tint * face_mean).mean(1, keepdim=True)  # brightness kept
    tinted = {**b, "sh_pseudo": b["sh_pseudo"] * tint}
    assert L.recon_L(out, tinted, gray=True).item() == pytest.approx(L.recon_L(out, b, gray=True).item(), rel=1e-5)
    assert L.recon_L(out, tinted).item() != pytest.approx(L.recon_L(out, b).item(), rel=1e-3)  # the paper's target
    gray = b["sh_pseudo"] * face_mean.mean(1, keepdim=True) / face_mean
    gray_s = (sh_shading(b["normal_pseudo"], gray) * mask).sum((2, 3))
    assert torch.allclose(gray_s, gray_s.mean(1, keepdim=True), rtol=1e-5)
    assert L.recon_L({"sh": gray}, b, c=None, gray=True).item() == pytest.approx(0, abs=1e-10)
    # the oracle target (loss.recon_L_target=sh): the true light, whitened and measured as L-hat is
    oracle = {**b, "sh": b["sh_pseudo"], "sh_pseudo": torch.zeros_like(b["sh_pseudo"])}
    assert L.recon_L(out, oracle, target="sh").item() == pytest.approx(L.recon_L(out, b).item(), rel=1e-6)
    with pytest.raises(ValueError, match="true light"):  # a batch without it (a folder of photos)
        L.recon_L(out, b, target="sh")
    textured = {**b, "sh_texture": b["sh_pseudo"], "sh_pseudo": torch.zeros_like(b["sh_pseudo"])}
    assert L.recon_L(out, textured, target="sh_texture").item() == pytest.approx(L.recon_L(out, b).item(), rel=1e-6)
    with pytest.raises(ValueError, match="the trainer to add it"):
        L.recon_L(out, b, target="sh_texture")
    with pytest.raises(ValueError, match="recon_L_target must be one of sh_pseudo, sh_pseudo_eroded, sh_texture, sh"):
        L.recon_L(out, b, target="L_hat")
    # the oracle mix (loss.recon_L_oracle_mix): a share m of the way from L-hat to the true light scaled to L-hat's
    # mean shading per face and channel; at m = 1 the truth's shape with L-hat's brightness and colour costs 0, the
    # truth at another scale per face and channel does not; with L-hat as the output the loss grows as m^2
    true = torch.randn(b["sh_pseudo"].shape, generator=torch.Generator().manual_seed(2)) * 0.2
    true[:, :, 0] += 1.0
    mixed = {**b, "sh": true}
    face_means = [
        (sh_shading(b["normal_pseudo"], sh) * mask).sum((2, 3)) / mask.sum((2, 3)) for sh in (true, b["sh_pseudo"])
    ]
    matched = true * (face_means[1] / face_means[0])[:, :, None]
    assert L.recon_L({"sh": matched}, mixed, c=None, oracle_mix=1.0).item() == pytest.approx(0, abs=1e-10)
    assert L.recon_L({"sh": 2 * matched}, mixed, c=None, oracle_mix=1.0).item() > 1e-3
    at_lhat = [L.recon_L({"sh": b["sh_pseudo"]}, mixed, c=None, oracle_mix=m).item() for m in (0.0, 0.5, 1.0)]
    assert at_lhat[0] == 0 and at_lhat[1] == pytest.approx(0.25 * at_lhat[2], rel=1e-5) and at_lhat[2] > 1e-3
    assert L.recon_L(out, mixed, oracle_mix=0.0).item() == L.recon_L(out, b).item()
    with pytest.raises(ValueError, match="recon_L_oracle_mix needs the true light"):
        L.recon_L(out, b, oracle_mix=0.5)
    # L-hat's per-face scale (loss.recon_L_scale=sh_pseudo): a target keeps its shape and takes L-hat's mean shading
    # per face and channel, so the truth's shape costs 0 at L-hat's scale and at its own it does not
    at_scale = {**b, "sh_texture": true}
    assert L.recon_L({"sh": matched}, at_scale, c=None, target="sh_texture", scale="sh_pseudo").item() == pytest.approx(
        0, abs=1e-10
    )
    assert L.recon_L({"sh": matched}, at_scale, c=None, target="sh_texture").item() > 1e-3
    assert L.recon_L(out, b, scale="sh_pseudo").item() == pytest.approx(L.recon_L(out, b).item(), rel=1e-6)
    with pytest.raises(ValueError, match="recon_L_scale must be one of target, sh_pseudo"):
        L.recon_L(out, b, scale="lhat")
    assert L.recon_fg({"foreground": b["image"] + 0.1 * mask + 0.3 * (1 - mask)}, b).item() == pytest.approx(
        0.01, rel=1e-5
    )
    with pytest.raises(KeyError, match="unknown loss terms"):
        L.generator_losses(out, b, {"recon": 1, "bwss": 1})


def test_the_uv_space_terms_and_the_ceiling_terms_are_their_masked_squared_errors():
    """E_UV and E_Ni (the implicit model) over the pixels and texels they cover, and the supervised ceiling's terms
    over the scored region (the true face inside M-hat), each a mean squared error of a known offset."""
    b = fake_batch()
    mask = b["mask_pseudo"]
    out = {"uv": b["uv_pseudo"] + 0.2 * mask + 5 * (1 - mask), "normal_uv": b["normal_uv_pseudo"] + 0.3}
    assert L.UV(out, b).item() == pytest.approx(0.04, rel=1e-5)  # only M-hat's pixels count
    covered = b["normal_uv_pseudo"].norm(dim=1, keepdim=True) > 0.5  # texels the pseudo fit covers
    assert covered.any() and not covered.all()
    assert L.Ni(out, b).item() == pytest.approx(0.09, rel=1e-5)
    truth = {**b, "albedo": torch.full_like(b["image"], 0.5), "normal": b["normal_pseudo"], "matte": mask}
    truth["sh"] = b["sh_pseudo"]
    guess = {"albedo": truth["albedo"] + 0.1, "normal": truth["normal"] - 0.2, "sh": truth["sh"] + 0.3}
    assert L.A_true(guess, truth).item() == pytest.approx(0.01, rel=1e-5)
    assert L.N_true(guess, truth).item() == pytest.approx(0.04, rel=1e-5)
    assert L.L_true(guess, truth).item() == pytest.approx(0.09, rel=1e-5)


def test_the_adversarial_term_is_the_discriminators_energy_of_the_output():
    """E_adv (Eq. 7): the generator pays D's energy of its image (EBGAN: D's autoencoder reconstruction error of
    it), weighted like every term into the total; without D's energy the term cannot be computed."""
    torch.manual_seed(0)
    b = fake_batch()
    D = Discriminator(R)
    out = {"recon": b["image"].clone()}
    energy = D.energy(out["recon"])
    losses = L.generator_losses(out, b, {"recon": 1.0, "adv": 0.5}, energy_fake=energy)
    assert losses["adv"].item() == pytest.approx((D(out["recon"]) - out["recon"]).pow(2).mean().item(), rel=1e-5)
    assert losses["total"].item() == pytest.approx(0.5 * losses["adv"].item(), rel=1e-6)  # recon is 0 here
    with pytest.raises(ValueError, match="needs energy_fake"):
        L.generator_losses(out, b, {"adv": 1.0})


def finite_difference(f, x: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """Central differences of the scalar ``f`` at ``x`` (float64)."""
    grad = torch.zeros_like(x)
    flat, g = x.view(-1), grad.view(-1)
    for i in range(flat.numel()):
        old = flat[i].item()
        flat[i] = old + eps
        up = f(x).item()
        flat[i] = old - eps
        down = f(x).item()
        flat[i] = old
        g[i] = (up - down) / (2 * eps)
    return grad


@pytest.mark.parametrize("term", ["BWS", "smooth_A", "smooth_S", "recon_L"])
def test_the_paper_terms_gradients_match_finite_differences(term):
    b = {k: v.double() for k, v in fake_batch(B=2, H=8).items()}
    torch.manual_seed(1)
    layer = {"BWS": "shading", "smooth_A": "albedo", "smooth_S": "shading", "recon_L": "sh"}[term]
    x = (b["sh_pseudo"] + 0.1 * torch.randn_like(b["sh_pseudo"])) if term == "recon_L" else torch.rand(2, 3, 8, 8)
    x = x.double().requires_grad_(True)

    def f(v):
        return getattr(L, term)({layer: v}, b)

    (analytic,) = torch.autograd.grad(f(x), x)
    numeric = finite_difference(lambda v: f(v.detach()), x.detach().clone())
    # |grad| of smooth_A's L1 is undefined only where a difference is exactly 0: random inputs never are
    torch.testing.assert_close(analytic, numeric, rtol=1e-4, atol=1e-7)


def test_recon_l_in_shading_space_is_the_masked_squared_shading_difference():
    """Eq. 9 measured on shadings (c off): ||S(N-hat, Z_L) - S(N-hat, L-hat)||^2 under M-hat, by Eq. 4's linearity
    the shading of the difference; a change along an SH direction the face cannot show costs nothing."""
    b = fake_batch()
    mask, normal = b["mask_pseudo"], b["normal_pseudo"]
    out = {"sh": b["sh_pseudo"] + torch.linspace(-0.1, 0.1, 27).reshape(1, 3, 9)}
    expected = ((sh_shading(normal, out["sh"]) - sh_shading(normal, b["sh_pseudo"])).pow(2) * mask).sum() / (
        mask.sum() * 3
    )
    assert L.recon_L(out, b, c=None).item() == pytest.approx(expected.item(), rel=1e-5)
    flat = {**b, "normal_pseudo": torch.zeros_like(normal) + torch.tensor([0.0, 0.0, 1.0])[None, :, None, None] * mask}
    yx = torch.zeros_like(b["sh_pseudo"])
    yx[:, :, 4] = 1.0  # the xy coefficient shades a frontal (n = +z) face by 0
    assert L.recon_L({"sh": b["sh_pseudo"] + yx}, flat, c=None).item() == pytest.approx(0, abs=1e-10)
