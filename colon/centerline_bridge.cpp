#include "colon/centerline_bridge.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <string>

namespace flyover {

namespace {

double angleBetween(const Vec3d& a, const Vec3d& b)
{
    const double la = length(a), lb = length(b);
    if (!(la > 0) || !(lb > 0)) return 0.0;
    return std::acos(std::clamp(dot(a, b) / (la * lb), -1.0, 1.0));
}

/// Where piece i is entered and left, and the outward tangents there, for a direction of travel.
struct Passage {
    Vec3d entryMm, entryOut, exitMm, exitOut;
};

Passage passage(const PieceEnds& p, bool reversed)
{
    return reversed ? Passage{p.backMm, p.backOut, p.frontMm, p.frontOut}
                    : Passage{p.frontMm, p.frontOut, p.backMm, p.backOut};
}

constexpr int EXACT_MAX_PIECES = 12;

} // namespace

double bridgeCostMm(const Vec3d& exitMm, const Vec3d& exitOut, const Vec3d& entryMm,
                    const Vec3d& entryOut, double turnPenaltyMmPerRad)
{
    const Vec3d gap = entryMm - exitMm;
    const double len = length(gap);
    if (!(len > 1e-9)) return 0.0;
    return len + turnPenaltyMmPerRad * (angleBetween(exitOut, gap) + angleBetween(entryOut, -gap));
}

PieceChain orderPieces(const std::vector<PieceEnds>& pieces, int first, bool firstReversed,
                       double turnPenaltyMmPerRad)
{
    const int n = static_cast<int>(pieces.size());
    if (first < 0 || first >= n)
        throw std::invalid_argument("orderPieces: first piece " + std::to_string(first) +
                                    " out of range (" + std::to_string(n) + " pieces)");
    PieceChain chain;
    auto cost = [&](int from, bool fromRev, int to, bool toRev) {
        const Passage a = passage(pieces[from], fromRev), b = passage(pieces[to], toRev);
        return bridgeCostMm(a.exitMm, a.exitOut, b.entryMm, b.entryOut, turnPenaltyMmPerRad);
    };

    if (n <= EXACT_MAX_PIECES) {
        // best[mask][2 * j + r]: least cost of a chain from `first` through the pieces of mask,
        // ending with piece j travelled in direction r.
        const std::size_t states = std::size_t(1) << n;
        const double INF = std::numeric_limits<double>::infinity();
        std::vector<double> best(states * 2 * n, INF);
        std::vector<std::int32_t> from(states * 2 * n, -1);
        auto at = [&](std::size_t mask, int j, int r) { return mask * 2 * n + 2 * j + r; };
        best[at(std::size_t(1) << first, first, firstReversed ? 1 : 0)] = 0.0;
        for (std::size_t mask = 1; mask < states; ++mask)
            for (int j = 0; j < n; ++j)
                for (int r = 0; r < 2; ++r) {
                    const double c = best[at(mask, j, r)];
                    if (c == INF) continue;
                    for (int k = 0; k < n; ++k) {
                        if (mask & (std::size_t(1) << k)) continue;
                        const std::size_t next = mask | (std::size_t(1) << k);
                        for (int s = 0; s < 2; ++s) {
                            const double nc = c + cost(j, r != 0, k, s != 0);
                            if (nc < best[at(next, k, s)]) {
                                best[at(next, k, s)] = nc;
                                from[at(next, k, s)] = 2 * j + r;
                            }
                        }
                    }
                }
        const std::size_t full = states - 1;
        int last = -1;
        for (int js = 0; js < 2 * n; ++js)
            if (best[at(full, js / 2, js % 2)] < INF &&
                (last < 0 || best[at(full, js / 2, js % 2)] < best[at(full, last / 2, last % 2)]))
                last = js;
        chain.costMm = best[at(full, last / 2, last % 2)];
        std::size_t mask = full;
        for (int js = last; js >= 0;) {
            chain.order.push_back(js / 2);
            chain.reversed.push_back(js % 2 != 0);
            const int prev = from[at(mask, js / 2, js % 2)];
            mask &= ~(std::size_t(1) << (js / 2));
            js = prev;
        }
        std::reverse(chain.order.begin(), chain.order.end());
        std::reverse(chain.reversed.begin(), chain.reversed.end());
        return chain;
    }

    std::vector<bool> used(n, false);
    chain.order.push_back(first);
    chain.reversed.push_back(firstReversed);
    used[first] = true;
    for (int step = 1; step < n; ++step) {
        const int j = chain.order.back();
        const bool r = chain.reversed.back();
        int bestK = -1;
        bool bestS = false;
        double bestC = std::numeric_limits<double>::infinity();
        for (int k = 0; k < n; ++k) {
            if (used[k]) continue;
            for (int s = 0; s < 2; ++s) {
                const double c = cost(j, r, k, s != 0);
                if (c < bestC) {
                    bestC = c;
                    bestK = k;
                    bestS = s != 0;
                }
            }
        }
        used[bestK] = true;
        chain.order.push_back(bestK);
        chain.reversed.push_back(bestS);
        chain.costMm += bestC;
    }
    return chain;
}

std::vector<Vec3d> bridgeCurve(const Vec3d& exitMm, const Vec3d& exitOut, const Vec3d& entryMm,
                               const Vec3d& entryOut, double maxChordMm)
{
    const double len = distance(exitMm, entryMm);
    const Vec3d p0 = exitMm, p1 = exitMm + normalize(exitOut) * (len / 3.0),
                p2 = entryMm + normalize(entryOut) * (len / 3.0), p3 = entryMm;
    // |B'(t)| <= 3 max |P(i+1) - P(i)|, so parameter steps of 1/count give chords of at most
    // 3 max leg / count.
    const double maxLeg = std::max({distance(p0, p1), distance(p1, p2), distance(p2, p3)});
    const std::size_t count = std::max<std::size_t>(
        1, static_cast<std::size_t>(std::ceil(3.0 * maxLeg / std::max(maxChordMm, 1e-6))));
    std::vector<Vec3d> out(count + 1);
    for (std::size_t i = 0; i <= count; ++i) {
        const double t = double(i) / double(count), u = 1.0 - t;
        out[i] = p0 * (u * u * u) + p1 * (3 * u * u * t) + p2 * (3 * u * t * t) + p3 * (t * t * t);
    }
    out.front() = exitMm;
    out.back() = entryMm;
    return out;
}

} // namespace flyover
