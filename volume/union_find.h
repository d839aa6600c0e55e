/// @file union_find.h
/// @brief Union-find (disjoint sets) over ids 0 .. n-1 with path halving; a set's root is its
/// smallest id, so labels follow the ids' order whatever the order of the unions.
#pragma once

#include <algorithm>
#include <cstddef>
#include <numeric>
#include <vector>

namespace flyover {

template <typename Id = int>
struct UnionFind {
    std::vector<Id> parent;  ///< more ids may be added with push_back(new id)
    explicit UnionFind(std::size_t n) : parent(n) { std::iota(parent.begin(), parent.end(), Id(0)); }
    Id find(Id x)
    {
        while (parent[x] != x) x = parent[x] = parent[parent[x]];
        return x;
    }
    /// @return whether a and b were in different sets
    bool unite(Id a, Id b)
    {
        a = find(a);
        b = find(b);
        if (a == b) return false;
        parent[std::max(a, b)] = std::min(a, b);
        return true;
    }
};

} // namespace flyover
