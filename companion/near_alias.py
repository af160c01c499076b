"""The near pass's alias check: a too-near claim of the coarse pass must beat the main
pass's own match of the same pixels at full resolution.

The coarse pass (:meth:`companion.stereo_bm.PaddedStereoBM.coarse_pass_fixed`) searches
4 × 48 = 192 px at a quarter of the resolution. On a repetitive surface (brick, windows, a
fence, or the synthetic camera's value-noise texture, whose coarse octave repeats every
32 × 0.12 m = 3.84 m) the right image holds a second copy of each block one texture period
to the left. When the period at the surface's distance is shorter than the search
(``f·period / Z < 192 px``: beyond 7.2 m for 3.84 m) the pass can lock on that copy: a wall
at 8-14 m became a surface at 0.39-0.68 m over a third to a half of the image. Its two
refusals are fooled by the same repetition:

* uniqueness compares SAD at integer coarse disparities, and the quarter-resolution image
  samples the texture near its Nyquist limit: the copy at an almost integer disparity
  costs less than half the true match at a fractional one (measured 15 against 37), so
  the true match does not count as a rival;
* the left/right check runs on the same cost volume and agrees with the copy.

The main pass ranged those pixels right (8.6-9.1 px for 7.9 m) and the merge let the
coarse claim win. The check here settles each claim where the main pass also matched: both
candidates are scored at full resolution (where the texture is well sampled) with the
Birchfield-Tomasi dissimilarity, which does not depend on where the pixel grid falls
(Birchfield & Tomasi, "A pixel dissimilarity measure that is insensitive to image
sampling", IEEE TPAMI 20(4), 1998). The claim stands only if the main pass's match costs
clearly more; where the main match costs clearly less it is kept and the claim dropped;
where neither is clearly better the pixels are ambiguous and become unknown (a repetitive
surface near the vehicle looks the same as one far away, so neither may be taken as free
or as the range). A claim where the main pass matched nothing (the usual case in front of
a real near surface: its disparity lies beyond the main search) is not touched.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["AliasCounts", "settle_near_claims"]

# Scale and block of the coarse pass (companion.stereo_bm's _NEAR_SCALE)
_SCALE = 4
# A candidate beats its rival when the rival's cost is at least this many times its own
# (plus the noise floor); between the two, the pixel is ambiguous. Measured on the synthetic
# camera (tests/test_near_alias.py's scenes, full-resolution BT costs): on the repetitive
# wall the main match costs 0.2-2.8 × the copy one period away; in front of a real surface
# at 0.5-1.3 m the main pass's alias costs 1-370 × the near match (95 % above 5 ×).
_WIN_RATIO = 3.0
_NOISE_FLOOR = 1.0  # [grey levels per pixel] added to both costs: noise is no evidence
_NEAR_SPREAD_PX = 1  # the claim is scored at its full-resolution disparity ± this [px]

#: :func:`settle_near_claims`'s verdict counts: (claims confirmed, claims dropped for the
#: main match, claims ambiguous (both unknown)).
AliasCounts = tuple[int, int, int]


@numba.njit(cache=True)
def _half_pixel_span(image):
    """Per pixel, twice the value (int16) and twice the least and greatest value the image
    takes within half a pixel of it along the row (linear interpolation; a border pixel
    only toward the inside): the intervals the Birchfield-Tomasi dissimilarity uses."""
    height, width = image.shape
    twice = np.empty((height, width), np.int16)
    lo = np.empty((height, width), np.int16)
    hi = np.empty((height, width), np.int16)
    for y in range(height):
        row = image[y]
        for x in range(width):
            v = np.int16(row[x])
            a = v + (np.int16(row[x - 1]) if x > 0 else v)
            b = v + (np.int16(row[x + 1]) if x < width - 1 else v)
            twice[y, x] = 2 * v
            lo[y, x] = min(2 * v, a, b)
            hi[y, x] = max(2 * v, a, b)
    return twice, lo, hi


@numba.njit(cache=True)
def _bt_cost(left, right, y0, x0, d, radius):
    """Mean Birchfield-Tomasi dissimilarity [grey levels] of the window of ``left`` around
    (``y0``, ``x0``) (``2·radius + 1`` columns, every other row of ``2·radius + 1``) against
    ``right`` shifted by the integer disparity ``d`` [px]: per pixel pair the smaller of
    the distance from the left value to the interval the right image spans within half a
    pixel of its sample, and the other way round, so a sub-pixel disparity costs no more
    than an integer one. ``left``, ``right``: :func:`_half_pixel_span` of each image.
    Columns whose pair leaves either image are skipped; -1 if more than half are."""
    l2, l_lo, l_hi = left
    r2, r_lo, r_hi = right
    height, width = l2.shape
    total = 0
    n = 0
    x_first = max(x0 - radius, d, 0)
    x_end = min(x0 + radius + 1, width, width + d)
    if x_end - x_first <= radius:
        return -1.0  # less than half the window: too few pixels to tell noise from texture
    for y in range(max(y0 - radius, 0), min(y0 + radius + 1, height), 2):
        for x in range(x_first, x_end):
            xr = x - d
            il = l2[y, x]
            ir = r2[y, xr]
            to_right = max(0, il - r_hi[y, xr], r_lo[y, xr] - il)
            to_left = max(0, ir - l_hi[y, x], l_lo[y, x] - ir)
            total += min(to_right, to_left)
        n += x_end - x_first
    if n == 0:
        return -1.0
    return total / (2.0 * n)  # the sums are of doubled grey levels


@numba.njit(cache=True)
def _block_median(disp, y0, x0, values):
    """Median of the non-negative entries of ``disp``'s ``_SCALE`` x ``_SCALE`` block at
    (``y0``, ``x0``) (``values`` is scratch of ``_SCALE²``); -1 if there is none."""
    n = 0
    for y in range(y0, min(y0 + _SCALE, disp.shape[0])):
        for x in range(x0, min(x0 + _SCALE, disp.shape[1])):
            if disp[y, x] >= 0:
                values[n] = disp[y, x]
                n += 1
    if n == 0:
        return -1
    for i in range(1, n):  # insertion sort of at most 16 values
        v = values[i]
        j = i - 1
        while j >= 0 and values[j] > v:
            values[j + 1] = values[j]
            j -= 1
        values[j + 1] = v
    return values[n // 2]


@numba.njit(cache=True)
def settle_near_claims(coarse, claim_above, disp, left, right, radius):
    """Settle each too-near claim of the coarse pass against the main pass, in place.

    Parameters
    ----------
    coarse : numpy.ndarray
        The coarse pass (int16, 1/16 coarse px, negative = unmatched), ``_SCALE`` times
        smaller than ``disp``; a claim is a match above ``claim_above``.
    claim_above : int
        The coarse disparity [1/16 coarse px] above which a match is nearer than the main
        pass reaches.
    disp : numpy.ndarray
        The main pass (int16, 1/16 px, negative = unmatched).
    left, right : numpy.ndarray
        The images the main pass matched (uint8, prefiltered, ``disp``'s shape).
    radius : int
        Half the scoring window [px].

    Returns
    -------
    tuple of int
        :data:`AliasCounts`. A dropped claim becomes unmatched (-16) in ``coarse``; an
        ambiguous one also makes the main pass's matches of its block unmatched in ``disp``.
    """
    values = np.empty(_SCALE * _SCALE, np.int16)
    # the claims the main pass rivals: (coarse row, column, the main pass's disparity)
    rivalled = np.empty((coarse.size, 3), np.int32)
    n_rivalled = 0
    for ys in range(coarse.shape[0]):
        for xs in range(coarse.shape[1]):
            if coarse[ys, xs] > claim_above:
                main = _block_median(disp, _SCALE * ys, _SCALE * xs, values)
                if main >= 0:  # else nothing rivals it: the main pass missed this surface
                    rivalled[n_rivalled, 0] = ys
                    rivalled[n_rivalled, 1] = xs
                    rivalled[n_rivalled, 2] = main
                    n_rivalled += 1
    kept = 0
    dropped = 0
    ambiguous = 0
    if n_rivalled == 0:
        return kept, dropped, ambiguous
    lspan = _half_pixel_span(left)
    rspan = _half_pixel_span(right)
    for i in range(n_rivalled):
        ys, xs, main = rivalled[i, 0], rivalled[i, 1], rivalled[i, 2]
        y0, x0 = _SCALE * ys, _SCALE * xs
        yc, xc = y0 + _SCALE // 2, x0 + _SCALE // 2
        cost_main = _bt_cost(lspan, rspan, yc, xc, (main + 8) // 16, radius)
        d_near = (_SCALE * np.int32(coarse[ys, xs]) + 8) // 16  # full-resolution px
        cost_near = -1.0
        for d in range(d_near - _NEAR_SPREAD_PX, d_near + _NEAR_SPREAD_PX + 1):
            cost = _bt_cost(lspan, rspan, yc, xc, d, radius)
            if cost >= 0.0 and (cost_near < 0.0 or cost < cost_near):
                cost_near = cost
        if cost_main < 0.0 or cost_near < 0.0:
            continue  # a window outside the images: the coarse pass's verdict stands
        if cost_main + _NOISE_FLOOR >= _WIN_RATIO * (cost_near + _NOISE_FLOOR):
            kept += 1
            continue
        coarse[ys, xs] = -16
        if cost_near + _NOISE_FLOOR >= _WIN_RATIO * (cost_main + _NOISE_FLOOR):
            dropped += 1
            continue
        ambiguous += 1
        for y in range(y0, min(y0 + _SCALE, disp.shape[0])):
            for x in range(x0, min(x0 + _SCALE, disp.shape[1])):
                disp[y, x] = -16
    return kept, dropped, ambiguous
