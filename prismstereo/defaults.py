"""How :class:`~prismstereo.model.PrismStereo` picks its defaults, and the measurements behind them.

The rules are the functions below (the model calls them); this docstring keeps, option by option, what was
measured for each default and its alternatives, so that a change of default starts from the numbers. Captures
are this package's renders (``thesis_setup1`` / ``thesis_setup2`` at 1024 x 768 unless said otherwise, 8-bit,
read noise 1/255, 2 x 2 supersampling); "coverage" is the share of co-visible reference pixels that are valid,
"false matches" the share of valid pixels that are not co-visible. Scripts: ``benchmarks/depth_targets.py``
(accuracy; 205-1511 mm unless ``--z-range`` says otherwise) and ``benchmarks/onnx_speed.py`` (speed, setup 1;
ratios are medians of same-round ratios to OpenCV StereoSGBM's time). Numbers marked "worst-cost fill" or
"slower graphs" were measured with the shift volume's invalid entries at the worst cost (see *The shift volume's
fill*) or on earlier, slower graphs.

Why coarse-to-fine
    Over the thesis' working range the correspondence moves ~365 px across the other half (``thesis_setup1``);
    a full-resolution search touches H x W_ref x 368 voxels per pass, the coarse level (f = 4) 1/64 of that and
    the fine band 11 / 368.

Why the rectified coarse level (``sampling``)
    ``depth_targets.py --sampling``, full resolution, both setups, with ``coarse_reach=1``: the final depth comes
    from the same exact fine band either way, and the rectified coarse level lands inside it more often:
    coverage 97.2-99.6 % against the sweep's 96.3-99.4 % (setup 1) and 96.4-98.6 % against 95.1-98.8 % (setup
    2; 228 mm: 97.2 vs 95.1 %, the sweep's lowest, near the 95 % target). The sweep is the more precise placement
    on setup 2 (whose row rectification leaves 0.1 px): mean errors 0.010-0.071 % against 0.012-0.087 % and fewer
    false matches (0.0-2.6 % against 0.0-4.6 %); on setup 1 the two are within 0.007 points. onnxruntime runs the
    rectified frame faster (228-1374 mm, four runs: 175-270 ms against 216-322 ms; the volume is a gather of rows
    instead of a bilinear ``grid_sample`` of 2.3 M samples). It is not exact as a *final* level: a shift compares
    windows of equal width, while the other half's image of a surface is stretched or squeezed across the window
    (anamorphic virtual cameras), which the per-pixel sweep follows. As a single level at half resolution, setup
    2, 1192 mm: 0.26 % mean error / 88.9 % coverage against the sweep's 0.11 % / 95.3 %. So a single level
    (f = 1) uses the sweep.

``cost``
    At half resolution (512 x 384, f = 2, 4 planes + slanted + step per setup): ZNCC with 4-direction SGM beat
    census with 8 directions on every capture of both setups in error and false matches (228 mm: setup 1 0.56 %
    -> 0.14 %, 10.7 % -> 7.8 % false; setup 2 11.9 % -> 2.9 % false) and coverage (setup 2 at 1192 mm 91.9 % ->
    95.0 %), and ZNCC's five box filters cost far less than the 24 shifted comparisons of a 5 x 5 census.

``census_threshold``
    The default 0.4 / 255 is no multiple of 1 / (255 f^2) (5 does not divide 2 f^2 for any f not a multiple of
    5), so differences of 8-bit pixels and of their f x f coarse averages never sit exactly on it: equal
    neighbours count as "not darker" robustly and torch and onnxruntime agree bit for bit (0.5 / 255 is such a
    multiple at f = 2 and 4 and made the coarse levels of the two runtimes differ).

``directions``
    Over 600-1450 mm (``depth_targets.py --z-range 600 1450 --slanted 900 --step 700 1000 --directions 2``,
    worst-cost fill) 2 directions saved ~9 % of the default pyramid's onnxruntime time but covered down to 94.1 % on
    setup 2 (1374 mm; 4 directions: 95.7 %).

``p1``, ``p2``
    1 and 8 are strong for ZNCC (measured better than 0.3 / 2.4 and 0.1 / 0.8 on the same captures): the coarse
    level only has to land within the fine band, which then re-estimates every pixel on its own.

``coarse_factor`` (:func:`default_coarse_factor`, :func:`pyramid_coarse_factor` for the binned model of a pyramid)
    f = 8 on a 1024 x 768 sensor loses the pixels within ~40 px of the other half's edge: the coarse windows span
    72 px. A narrow range at full resolution (600-1450 mm, 103 hypotheses) gets f = 4: onnxruntime 267 ms per
    frame at 0.048 % mean error, against 506 ms (0.053 %) with f = 2 and ~9x the time with a single level
    (measured before the onnxruntime tuning that brought f = 4 to 156-220 ms). The pyramid's binned model of that
    range (52 / 94 hypotheses with setup 1 / 2) got f = 2 by the rule of >= 24 hypotheses; f = 4 there
    (``coarse_factor=4``, worst-cost fill) took 0.84x the onnxruntime time (1.00x OpenCV SGBM's) with errors as low or
    lower, but covered 93.7 % of setup 2's step scene (700 / 1000 mm; f = 2: 95.6 %) (neither ``coarse_reach=2``
    nor a binned band of +-4 recovered it: 93.6 / 93.5 %). The pixels lost were not at the step but the ~35
    columns before the edge of the common field of view on the near plane, where the coarse estimate was off by
    a median 7.4 full-resolution steps (f = 2: 2.3): the shifts whose windows reach past the other half's edge
    lost to shorter ones, the invalid entries costing the worst value (see *The shift volume's fill* below).
    With 3/4 of it f = 4 covers that scene at 95.1 %, and the binned model of a pyramid takes the
    largest f leaving >= 12 hypotheses (:func:`pyramid_coarse_factor`): 600-1450 mm (``depth_targets.py
    --z-range 600 1450 --slanted 900 --step 700 1000``), mean errors 0.036-0.087 % (setup 1) and 0.030-0.064 %
    (setup 2; f = 2 before: 0.038-0.091 / 0.031-0.072 %), coverage 98.9-99.4 % / 95.5-97.2 % (98.8-99.4 /
    95.7-97.3 %), slanted plane 0.046 / 0.034 % on 99.0 / 97.0 %, step 98.2 / 95.1 % (98.2 / 95.6 %), false
    matches at setup 2's 1374 mm 1.20 % (2.22 %), in 0.84x the onnxruntime time (paired A/B); the wide range's
    binned models have f = 4 either way.

The shift volume's fill (``_SHIFT_FILL`` of :mod:`prismstereo.matching.levels`, not an option)
    The rectified search's entries that are not real samples (past the other half's edge or outside the pixel's
    own range) cost 3/4 of the worst cost (ZNCC: 1.5, between uncorrelated and anti-correlated) instead of the
    worst (``depth_targets.py``, 205-1511 mm unless said otherwise). The default pyramid: mean errors
    0.019-0.087 % / 0.011-0.063 % (setups 1 / 2; worst fill 0.015-0.088 / 0.012-0.064 %), coverage 96.9-99.3 % /
    96.0-98.6 % (97.2-99.5 / 95.9-98.7 %), setup 2's slanted plane 97.0 % (95.8 %), false matches at 228 mm 2.84 /
    1.41 % (2.82 / 1.57 %). ``downsample=1``: coverage 98.9-99.5 % / 96.7-99.1 % (97.2-99.6 / 96.4-98.5 %; setup
    1 at 228 mm 99.0 against 97.2 %), errors within 0.005 points. The half-size sensors (``--scale 2``, their
    default model): worst coverage 96.3 / 93.7 % (92.1 / 92.3 %). A neutral fill (1.0) covered as much with up to
    0.008 points more mean error on setup 2 (625 mm 0.030 against 0.026 %) and more errors above 2 %.

``band`` (:func:`pyramid_band` for the binned model of a pyramid)
    The binned model's estimate only places the full-resolution band. ``depth_targets.py --band 3`` against 5
    (the default pyramid, binned coarse factor 4): mean errors 0.015-0.088 % / 0.012-0.064 % (setups 1 / 2; with
    5: 0.015-0.088 / 0.012-0.065 %), coverage 97.2-99.5 % / 95.9-98.7 % (97.2-99.5 / 95.8-98.7 %), fewer false
    matches (228 mm: 2.8 / 1.6 % against 3.2 / 2.3 %; setup 2 at 1374 mm 0.7 against 1.2 %), the slanted plane
    0.028 / 0.019 % on 98.8 / 95.8 % (0.029 / 0.020 % on 98.8 / 96.2 %); ~9 % less onnxruntime time (paired
    A/B). Over 600-1450 mm (binned coarse factor 2) R = 2 against 3: the same coverage to 0.3 points, errors equal
    or lower, fewer false matches; R = 1 lost up to 1.7 points (setup 2, step scene 93.9 %).

``occluder_confidence``
    A false match (a pixel the other half does not see, matched to some texture) claims an other-half pixel and
    used to push the true match of that pixel out; at full resolution, setup 2 at 1374 mm, two noise
    realisations: coverage 94.4 / 95.4 % -> 95.6 / 96.0 % with 0.8 (0.7: 95.2 / 95.8 %), at the price of a few
    more false matches kept elsewhere (setup 1 at 228 mm 7.6 -> 8.7 %, step scene 1.6 -> 2.1 %).

``lr_threshold``
    At full resolution with 1 (coarse px): on setup 2 it removes nearly all false matches of far planes (780 /
    1374 mm: 1.6 / 1.1 % -> 0.03 / 0.1 %), but on setup 1 it rejects true matches (228 mm: coverage 95.5 ->
    83.7 %, 780 mm 98.7 -> 94.0 %; the same with 2 or 3 px: the other half's winner is far off, not slightly):
    the other half's pixel picks the lowest aggregated cost among all reference pixels that could see it, and
    where many reference pixels have no true match (near the common field of view's edge) one of their spurious
    minima wins. So it is off by default; the z-buffer test (``occlusion_tolerance``) handles occlusions.

``downsample`` (:func:`default_downsample`)
    The pyramid (k = 2, ``full_band`` 2) met the same depth targets as the full-resolution coarse level
    (``downsample=1``) with lower errors on setup 2 (0.012-0.065 against 0.012-0.087 %), fewer false matches
    (228 mm: 3.2 / 2.3 % against 8.5 / 4.6 %), coverage within -0.6 / +0.2 points on the planes and 0.2-1.1
    points lower on the slanted and step scenes, in ~0.55x the time (see ``full_band``); on smaller sensors the
    binned image is too small for its own f = 4 coarse level. Block values (k = 2, ``full_band=0``):
    onnxruntime 0.38-0.44x OpenCV SGBM's time against 2.09-2.11x with ``downsample=1`` (228-1374 mm, two runs on
    slower graphs), slanted plane 0.040 % mean error on 98.3 % (``downsample=1``: 0.027 % on 98.8 %); on the thesis
    planes (``depth_targets.py --downsample 2 --full-band 0``) the mean error stays <= 0.123 % (setup 1) / 0.132
    % (setup 2), coverage 94.0-99.2 % / 93.4-97.0 % (``downsample=1``: 97.2-99.6 / 96.4-98.5 %; both with
    ``coarse_reach=1``, without it 90.2-98.6 / 92.6-95.9 %): below the 95 % target at the nearest plane (setup
    1) and the far ones (setup 2, 780-1374 mm).

``coarse_reach``
    (Measured with the worst-cost fill of the shift volume; with 3/4 of it the coarse level loses less of the edge
    itself: a half-size setup 1 at 240 mm covers 96.6 % without the reach (91.8 % before), 97.7 % with it, at
    0.052 % mean error against 0.038 % (the reached pixels are the harder ones).)
    The coarse level loses a margin of about its window at the edges of the common field of view (at 228 mm with
    setup 1 that field is a strip of 144 of the 512 reference columns), and the bilinear upsampling of s blended
    the values of its invalid pixels into the valid ones next to them, misplacing the band there (on a half-size
    setup 1 at 240 mm the coverage went 91.8 -> 95.2 % from that alone, 95.7 % with the reached pixels). With 1
    (``depth_targets.py --downsample 1``, against 0): coverage 95.5-99.4 -> 97.2-99.6 % (setup 1) and
    96.0-98.1 -> 96.4-98.5 % (setup 2), mean errors within 0.002 points on setup 1 (up to +0.002 at 525 / 936 mm
    and the step scene) and equal or lower on setup 2 (1374 mm 0.092 -> 0.087 %); false matches fell on every
    setup 1 capture but 1374 mm (equal; 228 mm 8.65 -> 8.46 %, 312 mm 0.78 -> 0.47 %) and rose by 0.0-0.8 points
    on setup 2 (228 mm 3.85 -> 4.64 %, 1192 mm 1.79 -> 2.10 %). A radius of 2 covered more but let in more false
    matches (setup 2, 228 mm: 12.2 % without the confidence rule).

``reach_confidence``
    0.8 instead of 0.9 gave the same coverage to 0.1 point with up to 0.5 points more false matches (setup 2,
    228 mm 5.11 %).

``full_band``
    Against ``downsample=1``: mean errors 0.015-0.088 % vs 0.016-0.083 % (setup 1) and 0.012-0.064 % vs
    0.012-0.087 % (setup 2), coverage 97.2-99.5 % vs 97.2-99.6 % and 95.9-98.7 % vs 96.4-98.5 %, fewer false
    matches (228 mm: 2.8 vs 8.5 % / 1.6 vs 4.6 %), slanted plane 0.028 / 0.019 % (0.026 / 0.023 %), step 0.042 /
    0.029 % (0.049 / 0.033 %), at ~0.45x the time (228-1374 mm, two runs on slower graphs: onnxruntime 0.93-0.95x
    OpenCV SGBM's time against 2.09-2.11x, torch 1.11-1.24x against 2.44-2.56x). The extension radius of the
    binned estimate (binned pixels; setup 2 at 1374 / 936 mm, setup 1 at 228 mm): 4 gave 93.5 / 94.8 / 96.2 %
    coverage, 8 (the default's) 95.8 / 96.6 / 97.2 %, 12 and 16 no more (96.0 / 96.6 / 97.0 and 95.9 / 96.4 /
    96.6 %): the binned level loses a margin of about its windows near the edges of the other half, which its own
    coarse reach does not bridge (a coarse reach of 2 inside the binned model instead gave 95.2 / 96.3 / 96.8 %).
    With a radius of 2: R = 3 covered 0.1-1.2 points more on setup 2 with more false matches and ~15 % more
    time; R = 1 was ~7 % faster in onnxruntime and covered 1.2 points less on the slanted plane.

``validity``
    'calibrated' against 'thresholds' (the NCC >= 0.5, coarse uniqueness >= 0.3 and ``reach_confidence`` rules),
    ``benchmarks/dense_depth.py`` (held-out photographs as height fields, defocus; coverage / share off by > 1 %):
    Tsukuba 45.8 / 5.3 % against 40.9 / 6.9 %, Venus 53.8 / 1.3 % against 32.8 / 1.5 %, a weak surface 95.6 /
    0.06 % against 90.1 / 0.02 %, the f/6.25 defocus plane 88.3 % at 0.20 % mean error against 89.4 % at 0.21 %
    (both with ``wide_box``). On the thesis planes (``depth_targets.py``) it covers as much: setup 1 97.2-99.5 %
    (thresholds 97.2-99.5 %), setup 2 96.1-98.6 % (95.9-98.7 %), mean errors 0.018-0.087 % / 0.010-0.062 %
    (0.015-0.088 / 0.012-0.064 %), false matches at 228 mm 4.1 / 1.3 % (2.8 / 1.4 %). It costs ~6 ms of the
    onnxruntime frame at 1024 x 768 (paired A/B: 73 against 67 ms). Two designs that were measured and
    dropped: the binned model of a pyramid without thresholds of its own (every estimate placed as it is rather
    than rejected ones extended from their neighbours) lost 2-3 points on setup 2's far planes (92.9 % at
    1374 mm); filling the coarse estimate's holes by push-pull normalised convolution instead of the coarse
    level's own rejected estimate covered 94.2 % of Tsukuba in the dense output instead of 99.7 %. On a
    quarter-resolution setup 2 with a rolled prism and a distorting lens the calibrated rule keeps 92.0 % at
    0.20 % mean error where the thresholds keep 94.4 % at 0.25 %: 65 % of the 2.4 points it drops are off by
    more than 1 %.

``dense_fill``
    The dense output's pixels that are not valid take the mean s of the valid ones within the radius
    (``dense_depth.py``; share of the dense pixels off by > 1 %): their own estimates 37.0 / 17.3 / 0.55 / 1.8 %
    (Tsukuba / Venus / weak surface / f/6.25 plane); radius 7: 33.5 / 16.3 / 0.3 / 1.0 %; 15 (the default):
    31.9 / 15.1 / 0.1 / 0.5 %; 23: 33.2 / 14.2 / 0.1 / 0.5 %. Only pixels with confidence >= 0.8 as sources: no
    better (31.8 / 15.8 %). A guided filter (radius 7-31, guided by the reference) instead of the box: within
    1 point, worse at 31.

``wide_box``, ``weak_texture``
    The fine bands' cost blended with a wider box where the reference's 5 x 5 grey standard deviation is below
    ``weak_texture`` (``dense_depth.py`` with the calibrated confidence before refitting it; coverage / off by
    > 1 %): off: Tsukuba 41.5 / 5.8 %, Venus 46.3 / 1.7 %, f/6.25 76.3 %; 21 px below 4 / 255: 44.6 / 5.5, 52.5 /
    1.5, 78.8 %; 21 px below 8 / 255 (the default): 47.7 / 5.7, 56.9 / 1.3, 89.1 %; 31 px below 8 / 255: 49.6 /
    6.2, 58.9 / 1.2, 91.0 %. The thesis planes did not change (228 / 1374 mm: the same coverage to 0.1 point).
    Measured and dropped: a guided filter instead of box + SGM at the coarse level (radius 4 or 8 coarse
    pixels: coverage within 1 point, errors as high); SGM over the final band (P1 / P2 0.1 / 0.8 to 1 / 8, NCC
    threshold off, 400-1000 mm: Venus 83 -> 86-89 % covered at 4.0-5.0 % off by > 1 % against 4.6 %, Tsukuba
    60 -> 65-70 % at 11-18 % against 9 %, ~1.8x the torch time of the model), buying coverage with errors.
    Measured, not yet adopted (the confidence would need refitting, the thesis planes and the speed measuring):
    the binned model's coarse level at factor 2 and / or with census (``coarse_factor=2``, ``cost='census'``)
    on the photographs (valid / dense output, coverage and share off by > 1 %): Tsukuba 45.8 / 5.3 % -> 50.1 /
    4.6 % (factor 2), 48.7 / 5.1 % (census), 51.4 / 5.2 % (both), dense 37.0 -> 27.4 / 30.1 / 24.9 % off;
    Venus 53.8 / 1.3 % -> 56.0 / 1.5, 55.5 / 1.3, 57.6 / 1.4 %, dense 17.3 -> 14.6 / 14.5 / 13.8 % off. In
    onnxruntime (paired, 1024 x 768, 228-1374 mm) 1.37x / 1.04x / 1.84x the default's time; census on the thesis
    planes (the confidence not refitted): setup 1 at 228 / 1374 mm 97.5 / 99.6 % at 0.017 / 0.096 % mean error
    (ZNCC 97.2 / 99.5 % at 0.018 / 0.087 %), setup 2 at 625 / 1374 mm 96.8 / 96.1 % at 0.029 / 0.067 % (97.4 /
    96.1 % at 0.025 / 0.062 %).

``band_edges``
    With ``full_band=1`` (a band of 3) 'clamp' is the fast full-resolution setting: ``depth_targets.py
    --downsample 2 --full-band 1 --band-edges clamp`` gave mean errors 0.014-0.096 % (setup 1) and 0.012-0.079 %
    (setup 2), coverage 96.9-99.6 % and 96.3-98.7 %, slanted plane 0.030 / 0.025 %, step 0.046 / 0.034 % (the
    default pyramid: 0.015-0.088 %, 0.012-0.065 %, 97.2-99.5 %, 95.8-98.7 %, 0.029 / 0.020 %, 0.043 / 0.029 %),
    false matches at setup 2's 1374 mm 2.0 % (1.2 %), in 0.86-0.92x the default's onnxruntime time (slower graphs).
    With the binned band +-3 (slower graphs): 0.014-0.096 % / 0.012-0.081 %, 96.9-99.6 % / 96.3-98.7 %, slanted 0.030
    / 0.027 %, step 0.046 / 0.035 %, false 1.6 % at setup 2's 1374 mm; onnxruntime 0.64-0.75x OpenCV SGBM's time
    (228-1374 mm, two runs; the default pyramid 0.93-0.95x); without 'clamp' R = 1 covered 91.3-96.9 % on setup
    2. With R = 2, 'clamp' covered 0.1-1.2 points more on setup 2 (worst 96.3 %) at up to +0.008 points of mean
    error and ~1.8x the false matches at 1374 mm. With the worst-cost fill, over 600-1450 mm (``--z-range 600 1450
    --slanted 900 --step 700 1000``): the fast setting 0.95-0.97x OpenCV SGBM's time (96 disparities; the default
    pyramid 1.14-1.24x), errors 0.039-0.100 % / 0.041-0.098 % (default 0.038-0.091 % / 0.031-0.072 %), coverage
    98.3-99.5 % / 96.3-98.2 % (98.2-99.4 % / 95.6-97.3 %), but on setup 2 up to 3.9 % false matches (default
    2.2 %) and 0.67 % of pixels off by > 2 % (0.20 %).
"""

from __future__ import annotations

import math

from prismstereo.geometry.rig import BiPrismRig

__all__ = ["default_coarse_factor", "default_downsample", "pyramid_band", "pyramid_coarse_factor"]


def default_downsample(rig: BiPrismRig) -> int:
    """k = 2 (the pyramid, with ``full_band`` 2) when the reference half is at least 384 px on its shorter side,
    else 1 (coarse-to-fine at full resolution); see ``downsample`` in the module docstring.

    Args:
        rig: the rig.

    Returns:
        The binning k of :class:`~prismstereo.model.PrismStereo`'s ``downsample``.

    Example:
        >>> [default_downsample(thesis_setup1().downscaled(k)) for k in (1, 2)]
        [2, 1]
    """
    return 2 if min(rig.image_height, rig.reference_width) >= 384 else 1


def default_coarse_factor(num_hypotheses: int, height: int, width: int) -> int:
    """f = the largest power of two (<= 4) leaving >= 24 hypotheses and >= 32 rows and columns at the coarse
    level; 1 (a single full-resolution level) for small searches. See ``coarse_factor`` in the module docstring.

    Args:
        num_hypotheses: D of the level's image.
        height, width: the reference half's size (px) at that level.

    Returns:
        The coarse factor f.

    Example:
        >>> [default_coarse_factor(d, h, w) for d, h, w in ((368, 768, 512), (103, 768, 512), (40, 96, 64))]
        [4, 4, 1]
    """
    return _coarse_factor(num_hypotheses, height, width, 24)


def pyramid_coarse_factor(num_hypotheses: int, height: int, width: int) -> int:
    """The coarse factor of a pyramid's binned model: as :func:`default_coarse_factor`, leaving >= 12 hypotheses
    instead of 24, since its estimate only places the full-resolution band (``coarse_factor`` in the module
    docstring: the narrow range's binned model gets f = 4 instead of 2).

    Args:
        num_hypotheses: D of the binned image.
        height, width: the binned reference half's size (px).

    Returns:
        The coarse factor f.

    Example:
        >>> [pyramid_coarse_factor(d, 384, 256) for d in (52, 47, 222)], default_coarse_factor(52, 384, 256)
        ([4, 2, 4], 2)
    """
    return _coarse_factor(num_hypotheses, height, width, 12)


def _coarse_factor(num_hypotheses: int, height: int, width: int, least: int) -> int:
    """The largest power of two f <= 4 leaving >= ``least`` hypotheses and >= 32 rows and columns."""
    f = 1
    while f < 4 and num_hypotheses / (2 * f) >= least and min(height, width) / (2 * f) >= 32:
        f *= 2
    return f


def pyramid_band(coarse_factor: int) -> int:
    """Half width R of the binned model's band in a pyramid: ceil(3 f / 4) (f = 4 -> 3, f = 2 -> 2), against
    f + 1 for a model's own band, since its estimate only places the full-resolution band (``band`` in the
    module docstring).

    Args:
        coarse_factor: the binned model's coarse factor f (> 1).

    Returns:
        R.

    Example:
        >>> [pyramid_band(f) for f in (2, 4)]
        [2, 3]
    """
    return math.ceil(3 * coarse_factor / 4)
