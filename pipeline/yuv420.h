/// @file yuv420.h
/// @brief RGB frames to planar YUV 4:2:0 for the H.264 encoder (SSE2 where there is).
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace flyover {

#if defined(__SSE2__)
namespace yuv_detail {
// Four RGB pixels from p (reads 16 bytes: 4 past the 4th pixel) as 16-bit lanes R G B G of
// pixels 0 and 1 (`lo`) and of pixels 2 and 3 (`hi`): G twice, so that a coefficient too large
// for 16 bits goes as two halves through _mm_madd_epi16.
inline void gatherRgbg(const uint8_t* p, __m128i& lo, __m128i& hi)
{
    const __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(p));
    const __m128i zero = _mm_setzero_si128();
    const __m128i p01 = _mm_unpacklo_epi32(v, _mm_srli_si128(v, 3));
    const __m128i p23 = _mm_unpacklo_epi32(_mm_srli_si128(v, 6), _mm_srli_si128(v, 9));
    lo = _mm_unpacklo_epi8(p01, zero);
    hi = _mm_unpacklo_epi8(p23, zero);
    lo = _mm_shufflehi_epi16(_mm_shufflelo_epi16(lo, _MM_SHUFFLE(1, 2, 1, 0)), _MM_SHUFFLE(1, 2, 1, 0));
    hi = _mm_shufflehi_epi16(_mm_shufflelo_epi16(hi, _MM_SHUFFLE(1, 2, 1, 0)), _MM_SHUFFLE(1, 2, 1, 0));
}

// Sums of adjacent 32-bit lanes: [a0 + a1, a2 + a3, b0 + b1, b2 + b3].
inline __m128i pairSums(__m128i a, __m128i b)
{
    const __m128 fa = _mm_castsi128_ps(a), fb = _mm_castsi128_ps(b);
    return _mm_add_epi32(_mm_castps_si128(_mm_shuffle_ps(fa, fb, _MM_SHUFFLE(2, 0, 2, 0))),
                         _mm_castps_si128(_mm_shuffle_ps(fa, fb, _MM_SHUFFLE(3, 1, 3, 1))));
}

// cR * R + cG * G + cB * B of the four gathered pixels, exact in 32 bits.
inline __m128i weigh(__m128i lo, __m128i hi, __m128i coeffs)
{
    return pairSums(_mm_madd_epi16(lo, coeffs), _mm_madd_epi16(hi, coeffs));
}
} // namespace yuv_detail
#endif

/// RGB (3 bytes per pixel, row-major) to planar YUV 4:2:0 as H.264 takes it: BT.601 limited
/// range (Y 16..235, Cb and Cr 16..240), each chroma sample from the mean of its 2 x 2 block of
/// pixels (centred siting, as ffmpeg's scaler takes it from RGB). Fixed point with 16-bit
/// coefficients, rounded to nearest. `yuv` gets width * height luma bytes, then the Cb and the
/// Cr plane of (width / 2) * (height / 2) bytes each. Width and height must be even. With SSE2,
/// eight pixels at a time, byte for byte the same as the scalar rule, in half the CPU time.
/// @throw std::invalid_argument for odd or non-positive sizes or a buffer of the wrong size
inline void rgbToYuv420(const uint8_t* rgb, int width, int height, std::vector<uint8_t>& yuv)
{
    if (width <= 0 || height <= 0 || width % 2 != 0 || height % 2 != 0)
        throw std::invalid_argument("rgbToYuv420: width and height must be even and positive, got " +
                                    std::to_string(width) + " x " + std::to_string(height));
    // Y = 16 + (65.481 R + 128.553 G + 24.966 B) / 255 and so on (Rec. 601), times 2^16.
    constexpr auto fix = [](double c) { return int32_t(c / 255.0 * 65536.0 + (c < 0 ? -0.5 : 0.5)); };
    constexpr int32_t YR = fix(65.481), YG = fix(128.553), YB = fix(24.966);
    constexpr int32_t UR = fix(-37.797), UG = fix(-74.203), UB = fix(112.0);
    constexpr int32_t VR = fix(112.0), VG = fix(-93.786), VB = fix(-18.214);
    constexpr int32_t YOffset = (16 << 16) + (1 << 15), UVOffset = (128 << 18) + (1 << 17);
    const std::size_t w = std::size_t(width), h = std::size_t(height), cw = w / 2;
    yuv.resize(w * h + 2 * cw * (h / 2));
    uint8_t* yPlane = yuv.data();
    uint8_t* uPlane = yPlane + w * h;
    uint8_t* vPlane = uPlane + cw * (h / 2);
#if defined(__SSE2__)
    // SSE2, eight pixels of two rows at a time; every value is the same integer expression as in
    // the scalar rule below (exact in 32 bits, so the order of the sums does not matter; a chroma
    // sum weighs each of the four pixels and adds them, which is the weighted sum of the block).
    static_assert(YG / 2 + 1 < 32768 && YR < 32768 && YB < 32768 && UB < 32768 && VR < 32768 &&
                      -UR < 32768 && -UG < 32768 && -VG < 32768 && -VB < 32768,
                  "16-bit coefficients for _mm_madd_epi16");
    const __m128i yCoeffs = _mm_setr_epi16(int16_t(YR), int16_t(YG - YG / 2), int16_t(YB), int16_t(YG / 2),
                                           int16_t(YR), int16_t(YG - YG / 2), int16_t(YB), int16_t(YG / 2));
    const __m128i uCoeffs = _mm_setr_epi16(int16_t(UR), int16_t(UG), int16_t(UB), 0, int16_t(UR), int16_t(UG), int16_t(UB), 0);
    const __m128i vCoeffs = _mm_setr_epi16(int16_t(VR), int16_t(VG), int16_t(VB), 0, int16_t(VR), int16_t(VG), int16_t(VB), 0);
    const __m128i yOffset = _mm_set1_epi32(YOffset), uvOffset = _mm_set1_epi32(UVOffset);
    // A group of eight pixels reads 4 bytes past its last one: stop 2 pixels (6 bytes) early.
    const std::size_t vectorEnd = w >= 10 ? (w - 2) / 8 * 8 : 0;
#endif
    for (std::size_t cy = 0; cy < h / 2; ++cy) {
        const uint8_t* a = rgb + 2 * cy * w * 3;
        const uint8_t* b = a + w * 3;
        uint8_t* ya = yPlane + 2 * cy * w;
        uint8_t* yb = ya + w;
        uint8_t* u = uPlane + cy * cw;
        uint8_t* v = vPlane + cy * cw;
        std::size_t x = 0;
#if defined(__SSE2__)
        for (; x < vectorEnd; x += 8) {
            __m128i a0, a1, a2, a3, b0, b1, b2, b3;  // pixels x..x+3 (0, 1) and x+4..x+7 (2, 3)
            yuv_detail::gatherRgbg(a + 3 * x, a0, a1);
            yuv_detail::gatherRgbg(a + 3 * x + 12, a2, a3);
            yuv_detail::gatherRgbg(b + 3 * x, b0, b1);
            yuv_detail::gatherRgbg(b + 3 * x + 12, b2, b3);
            auto luma = [&](__m128i lo0, __m128i hi0, __m128i lo1, __m128i hi1, uint8_t* out) {
                const __m128i l0 = _mm_srai_epi32(_mm_add_epi32(yuv_detail::weigh(lo0, hi0, yCoeffs), yOffset), 16);
                const __m128i l1 = _mm_srai_epi32(_mm_add_epi32(yuv_detail::weigh(lo1, hi1, yCoeffs), yOffset), 16);
                const __m128i w16 = _mm_packs_epi32(l0, l1);
                _mm_storel_epi64(reinterpret_cast<__m128i*>(out), _mm_packus_epi16(w16, w16));
            };
            luma(a0, a1, a2, a3, ya + x);
            luma(b0, b1, b2, b3, yb + x);
            auto chroma = [&](__m128i coeffs, uint8_t* out) {
                const __m128i s0 = _mm_add_epi32(yuv_detail::weigh(a0, a1, coeffs), yuv_detail::weigh(b0, b1, coeffs));
                const __m128i s1 = _mm_add_epi32(yuv_detail::weigh(a2, a3, coeffs), yuv_detail::weigh(b2, b3, coeffs));
                const __m128i c = _mm_srai_epi32(_mm_add_epi32(yuv_detail::pairSums(s0, s1), uvOffset), 18);
                const __m128i c16 = _mm_packs_epi32(c, c);
                const int32_t bytes = _mm_cvtsi128_si32(_mm_packus_epi16(c16, c16));
                std::memcpy(out, &bytes, 4);
            };
            chroma(uCoeffs, u + x / 2);
            chroma(vCoeffs, v + x / 2);
        }
#endif
        for (; x < w; x += 2) {
            for (const uint8_t* in : {a, b}) {
                uint8_t* out = in == a ? ya : yb;
                for (std::size_t k = x; k < x + 2; ++k)
                    out[k] = uint8_t((YR * in[3 * k] + YG * in[3 * k + 1] + YB * in[3 * k + 2] + YOffset) >> 16);
            }
            const std::size_t i = 3 * x;
            // Sums of the four pixels: the mean's coefficients are a quarter, hence >> 18.
            const int32_t r = a[i] + a[i + 3] + b[i] + b[i + 3];
            const int32_t g = a[i + 1] + a[i + 4] + b[i + 1] + b[i + 4];
            const int32_t bl = a[i + 2] + a[i + 5] + b[i + 2] + b[i + 5];
            u[x / 2] = uint8_t((UR * r + UG * g + UB * bl + UVOffset) >> 18);
            v[x / 2] = uint8_t((VR * r + VG * g + VB * bl + UVOffset) >> 18);
        }
    }
}

} // namespace flyover
