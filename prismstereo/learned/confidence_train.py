"""Train the exact chain's confidence head (:mod:`~prismstereo.learned.exact_confidence`) on the hybrid's renders.

After the refinement (:func:`~prismstereo.learned.hybrid_train.train_hybrid`), the renders of each rig variant
(:func:`head_rigs`: the refinement's, whose captures, seeds and cache it shares, and two 512 x 384 sensors;
:func:`~prismstereo.learned.hybrid_data.render_set`) go once
through the trained hybrid with its exact last stage, without gradients: the head's features
(:func:`~prismstereo.learned.exact_confidence.exact_features`) and the target, a final depth within 1 % of the true
one (0 where the other half cannot see the point: its depth is wrong or, at best, right by chance). The first half of
each variant's captures fit the head; the second half, which the head never saw, calibrates its validity threshold:
the one that keeps as many of their known pixels valid as the learned confidence does at its own calibrated threshold
(:func:`~prismstereo.learned.hybrid_train.validity_threshold`), so the chain stays as dense as it was and the head
only chooses better which pixels those are. (A threshold by the learned rule itself, the lowest confidence at which at
most 3 % of these captures' depths are wrong, lies higher for the head: it finds more of their wrong depths, and the
held-out captures, easier than these, then lose valid pixels, defocused planes among them.) The weights file records
the share of those pixels each confidence keeps wrong (``head_calibration_bad``).

A step: ``batch_size`` random crops of the fitting captures (a variant drawn by its number of captures), the binary
cross-entropy of the head's logit on the pixels with a true depth; Adam at 3e-3, 1e-3 for the last third. The head
trains in under a minute on 2 cores, so it keeps no checkpoint; the refinement before it does.

The shipped ``weights/hybrid.pt`` holds the head trained by ``prismstereo train --model hybrid`` (the refinement, then
this; the options are in the file's metadata: ``head_steps``, ``head_seed``).
"""

from __future__ import annotations

import time
from pathlib import Path

import torch
import torch.nn.functional as F

from prismstereo.errors import OptionError, check_int
from prismstereo.geometry.presets import thesis_setup1, thesis_setup2
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.learned.exact_confidence import HEAD_CHANNELS, ConfidenceHead, exact_features
from prismstereo.learned.hybrid import HybridStereo
from prismstereo.learned.hybrid_data import render_set, training_rigs
from prismstereo.learned.hybrid_train import correct_depth
from prismstereo.learned.train import TrainResult

__all__ = ["head_inputs", "head_rigs", "train_exact_confidence"]


def head_rigs() -> list[tuple[str, BiPrismRig, tuple[float, float]]]:
    """The (name, rig, range) variants the head trains on: the refinement's
    (:func:`~prismstereo.learned.hybrid_data.training_rigs`, 1024 x 768, where the stages run on 2 x 2 bins) and both
    thesis setups at 512 x 384, where they run at full resolution: the texture and spread the head reads are per pixel
    of that grid.

    Example:
        >>> [name for name, _, _ in head_rigs()][-2:]
        ['setup1 512', 'setup2 512']
    """
    s1, s2 = thesis_setup1(), thesis_setup2()
    return [*training_rigs(), ("setup1 512", s1.downscaled(2), (228.0, 1374.0)),
            ("setup2 512", s2.downscaled(2), (220.0, 1280.0))]


def head_inputs(model: HybridStereo, grey: torch.Tensor, truth: torch.Tensor,
                known: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The head's features and target of captures on the stages' grid, through ``model`` (its stages; no gradients).

    Args:
        model: a trained hybrid with the exact last stage.
        grey: (B, 1, h, W2) grey captures on the stages' grid (:class:`~prismstereo.learned.hybrid_data.Rendered`).
        truth: (B, 1, h, w) their true sweep coordinates; known: (B, 1, h, w) bool, where that truth is reliable
            and seen by the other half.

    Returns:
        ((B, 6, h, w) features, (B, 1, h, w) bool: the final depth within 1 % of the truth).

    Raises:
        OptionError: a model without the exact stage.

    Example:
        >>> features, right = head_inputs(model, data.grey[:1], data.truth[:1], data.known[:1])  # doctest: +SKIP
    """
    if model.exact is None:
        raise OptionError("the confidence head judges the exact stage's evidence: build the model with "
                          "last_stage='exact'")
    with torch.no_grad():
        s, logit = model.refine(model.initial_binned(grey))[-1]
        evidence = model.exact.evidence(grey, s)
        return exact_features(evidence, logit, model.step), correct_depth(model, evidence.s, truth, known)


def train_exact_confidence(
    weights: str | Path,
    out_path: str | Path | None = None,
    *,
    steps: int = 1500,
    seed: int = 0,
    batch_size: int = 4,
    crop: int = 128,
    channels: int = HEAD_CHANNELS,
    captures: int = 24,
    cache: str | Path | None = None,
    variants: list[tuple[str, BiPrismRig, tuple[float, float]]] | None = None,
    progress: bool = True,
) -> TrainResult:
    """Train the confidence head of the hybrid weights ``weights`` and write them with it (module docstring).

    Args:
        weights: a hybrid weights file (its refinement trained; a head in it is replaced).
        out_path: the file to write (default: ``weights`` itself).
        steps: optimiser steps (>= 1).
        seed: seeds the head's initialisation and crops, and (as the refinement's ``seed``) the renders.
        batch_size: crops per step.
        crop: the crops' side on the stages' grid (smaller captures: the whole of them).
        channels: the head's hidden channels.
        captures: captures per variant (>= 2: half fit, half calibrate).
        cache: folder of the rendered sets (the refinement's).
        variants: (name, rig, range) rig variants (default :func:`head_rigs`; variant i renders with seed
            100 ``seed`` + i, as the refinement's do).
        progress: progress bars.

    Returns:
        TrainResult(losses, seconds, path).

    Raises:
        OptionError: bad ``steps``, ``batch_size``, ``crop``, ``channels`` or ``captures``. WeightsError: an unreadable
            file, or one whose refinement does not fit.

    Example:
        >>> result = train_exact_confidence("hybrid.pt", cache=".cache/hybrid")  # doctest: +SKIP
    """
    for name, value, low in (("steps", steps, 1), ("batch_size", batch_size, 1), ("crop", crop, 8),
                             ("channels", channels, 1), ("captures", captures, 2)):
        check_int(value, name, low)
    out_path = Path(weights if out_path is None else out_path)
    variants = head_rigs() if variants is None else variants
    features, right, rays, calibration = _render(weights, variants, captures, seed, cache, progress)
    torch.manual_seed(seed)
    head = ConfidenceHead(channels)
    optimiser = torch.optim.Adam(head.parameters(), lr=3e-3)
    gen = torch.Generator().manual_seed(seed)
    counts = torch.tensor([float(f.shape[0]) for f in features])
    losses = torch.zeros(steps, dtype=torch.float64)
    start = time.perf_counter()
    from tqdm.auto import tqdm

    for step in tqdm(range(steps), desc="train confidence head", disable=not progress):
        if step == 2 * steps // 3:
            for group in optimiser.param_groups:
                group["lr"] = 1e-3
        v = int(torch.multinomial(counts, 1, generator=gen))
        x, y, m = _crops(features[v], right[v], rays[v], batch_size, crop, gen)
        logit = head(x)
        loss = (F.binary_cross_entropy_with_logits(logit, y, reduction="none") * m).sum() / m.sum().clamp_min(1)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        losses[step] = float(loss.detach())
    seconds = time.perf_counter() - start
    model = HybridStereo(variants[0][1], variants[0][2], weights=weights, last_stage="learned")
    threshold, learned_bad, head_bad = _threshold(head, calibration, model.valid_confidence)
    model.head = head
    path = model.save(out_path, exact_valid_confidence=threshold, head_steps=steps, head_seed=seed,
                      head_seconds=round(seconds, 1), head_calibration_bad={"learned": round(learned_bad, 4),
                                                                             "head": round(head_bad, 4)})
    return TrainResult(losses, seconds, path)


def _render(weights: str | Path, variants: list[tuple[str, BiPrismRig, tuple[float, float]]], captures: int,
            seed: int, cache: str | Path | None, progress: bool):
    """Per variant: the fitting captures' features, targets and ray masks; and the calibrating captures' (features,
    targets, known) triples pooled (the threshold counts the pixels the other half sees, as the targets do)."""
    features, right, rays, calibration = [], [], [], []
    half = captures // 2
    for i, (name, rig, z_range) in enumerate(variants):
        model = HybridStereo(rig, z_range, weights=weights).eval()
        data = render_set(name, rig, z_range, captures, seed=seed * 100 + i, cache=cache, progress=progress,
                          binning=model.binning)
        maps = [head_inputs(model, data.grey[j:j + 1].to(torch.get_default_dtype()), data.truth[j:j + 1],
                            data.known[j:j + 1]) for j in range(captures)]
        features.append(torch.cat([f for f, _ in maps[:half]]))
        right.append(torch.cat([r for _, r in maps[:half]]))
        rays.append(data.rays[:half])
        calibration.extend((f, r, data.known[half + k]) for k, (f, r) in enumerate(maps[half:]))
    return features, right, rays, calibration


def _crops(features: torch.Tensor, right: torch.Tensor, rays: torch.Tensor, batch_size: int, crop: int,
           gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``batch_size`` random crops (features, target, mask) of one variant's maps."""
    n, _, h, w = features.shape
    ch, cw = min(crop, h), min(crop, w)
    xs, ys, ms = [], [], []
    for _ in range(batch_size):
        i, r, c = (int(torch.randint(k, (1,), generator=gen)) for k in (n, h - ch + 1, w - cw + 1))
        xs.append(features[i:i + 1, :, r:r + ch, c:c + cw])
        ys.append(right[i:i + 1, :, r:r + ch, c:c + cw].to(features.dtype))
        ms.append(rays[i:i + 1, :, r:r + ch, c:c + cw].to(features.dtype))
    return torch.cat(xs), torch.cat(ys), torch.cat(ms)


def _threshold(head: ConfidenceHead, calibration: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]],
               learned_threshold: float) -> tuple[float, float, float]:
    """The head's validity threshold on the calibrating captures' known pixels: the one that keeps as many of them
    valid as the learned confidence does at ``learned_threshold``; with the share of those each keeps wrong."""
    head_conf, learned_conf, correct = [], [], []
    with torch.no_grad():
        for features, right, known in calibration:
            mask = known.unsqueeze(0)
            head_conf.append(torch.sigmoid(head(features))[mask])
            learned_conf.append(torch.sigmoid(features[:, :1])[mask])
            correct.append(right[mask])
    confidence, learned, right = torch.cat(head_conf), torch.cat(learned_conf), torch.cat(correct)
    kept = learned >= learned_threshold
    count = int(kept.sum())
    if count == 0:
        return 1.0, float("nan"), float("nan")
    order = torch.argsort(confidence, descending=True, stable=True)
    threshold = float(confidence[order[count - 1]])
    valid = confidence >= threshold
    return round(threshold, 4), float((~right[kept]).double().mean()), float((~right[valid]).double().mean())
