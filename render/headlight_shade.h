/// @file headlight_shade.h
/// @brief The headlight shade of renderView (internal to render/, included by its tests):
///        ambient + diffuse * |cos| between the ray and the shading normal, divided by the
///        depth cue; per lane, and for many lanes at once with SSE (the same bits).
#pragma once

#include <algorithm>
#include <cmath>

#ifdef __SSE2__
#include <immintrin.h>
#endif

namespace flyover::detail {

constexpr float AMBIENT = 0.15f;
constexpr float DIFFUSE = 0.85f;

/// The shade in [0, 1] of one ray (direction d, any length) hitting a surface of shading normal
/// n (any length; zero gives the ambient) at depth t. invCueRangeMm 0: no depth cue.
inline float headlightShade(float dx, float dy, float dz, float nx, float ny, float nz, float t, float invCueRangeMm,
                            float cueStartMm)
{
    const float norms = (dx * dx + dy * dy + dz * dz) * (nx * nx + ny * ny + nz * nz);
    // A zero normal (degenerate face, or a miss) gives cos = 0: |0| / sqrt(FLT_MIN) = 0.
    const float cosine = std::fabs(dx * nx + dy * ny + dz * nz) / std::sqrt(std::max(norms, 1e-30f));
    float s = AMBIENT + DIFFUSE * std::min(cosine, 1.0f);
    if (invCueRangeMm > 0.0f) s /= 1.0f + std::max(0.0f, t - cueStartMm) * invCueRangeMm;
    return s;
}

/// headlightShade of `count` lanes (a multiple of 4) from arrays of 16-byte alignment, into
/// `out`. With SSE2, four lanes at a time: the same float operations in the same order (packed
/// sqrt and division round exactly as the scalar ones; min/max take their operands in the
/// order that gives std::min/std::max's result, NaN included), so the same bits. The scalar
/// loop is not vectorised by the compiler (std::sqrt may set errno), and the latency of its
/// sqrt and two divisions was a fifth of renderView's own time.
inline void headlightShadeLanes(const float* dx, const float* dy, const float* dz, const float* nx, const float* ny,
                                const float* nz, const float* t, int count, float invCueRangeMm, float cueStartMm,
                                float* out)
{
#ifdef __SSE2__
    const __m128 tiny = _mm_set1_ps(1e-30f), one = _mm_set1_ps(1.0f), zero = _mm_setzero_ps();
    const __m128 ambient = _mm_set1_ps(AMBIENT), diffuse = _mm_set1_ps(DIFFUSE);
    const __m128 absMask = _mm_castsi128_ps(_mm_set1_epi32(0x7fffffff));
    const __m128 invCue = _mm_set1_ps(invCueRangeMm), cueStart = _mm_set1_ps(cueStartMm);
    for (int i = 0; i < count; i += 4) {
        const __m128 ax = _mm_load_ps(dx + i), ay = _mm_load_ps(dy + i), az = _mm_load_ps(dz + i);
        const __m128 bx = _mm_load_ps(nx + i), by = _mm_load_ps(ny + i), bz = _mm_load_ps(nz + i);
        const __m128 dd = _mm_add_ps(_mm_add_ps(_mm_mul_ps(ax, ax), _mm_mul_ps(ay, ay)), _mm_mul_ps(az, az));
        const __m128 nn = _mm_add_ps(_mm_add_ps(_mm_mul_ps(bx, bx), _mm_mul_ps(by, by)), _mm_mul_ps(bz, bz));
        const __m128 dn = _mm_add_ps(_mm_add_ps(_mm_mul_ps(ax, bx), _mm_mul_ps(ay, by)), _mm_mul_ps(az, bz));
        // std::max(norms, tiny) is norms < tiny ? tiny : norms, i.e. _mm_max_ps(tiny, norms).
        const __m128 cosine = _mm_div_ps(_mm_and_ps(dn, absMask), _mm_sqrt_ps(_mm_max_ps(tiny, _mm_mul_ps(dd, nn))));
        __m128 s = _mm_add_ps(ambient, _mm_mul_ps(diffuse, _mm_min_ps(one, cosine)));
        if (invCueRangeMm > 0.0f) {
            const __m128 depth = _mm_max_ps(_mm_sub_ps(_mm_load_ps(t + i), cueStart), zero);
            s = _mm_div_ps(s, _mm_add_ps(one, _mm_mul_ps(depth, invCue)));
        }
        _mm_storeu_ps(out + i, s);
    }
#else
    for (int i = 0; i < count; ++i)
        out[i] = headlightShade(dx[i], dy[i], dz[i], nx[i], ny[i], nz[i], t[i], invCueRangeMm, cueStartMm);
#endif
}

} // namespace flyover::detail
