// Tests of canopy.bvh: the binned SAH builder's contract (every primitive once, ids, bounds,
// depth, leaf sizes), statistics, instance bounds, degenerate inputs and refits, each checked by
// walking the tree independently of the library.
#include <catch2/catch.hpp>
#include <tbb/global_control.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <random>
#include <span>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

import canopy.query;
import canopy.testing;

namespace {

using canopy::ray;
using canopy::triangle;
using canopy::vec3;
using mesh_bvh = canopy::bvh<triangle>;
using test_support::random_source;

constexpr float inf = std::numeric_limits<float>::infinity();

// test_support::triangle_soup with ids the builder must fix: every prim_id 12345, geom_id = index mod 7.
std::vector<triangle> soup_to_renumber(random_source& rng, int count, float extent, float size) {
    std::vector<triangle> soup;
    for (int i = 0; i < count; ++i) {
        vec3<float> const c = rng.point(-extent, extent);
        // prim_id deliberately wrong: the builder must renumber; geom_id is the user's and is kept.
        soup.push_back({c + rng.point(-size, size), c + rng.point(-size, size), c + rng.point(-size, size),
                        std::uint32_t(12345), std::uint32_t(i % 7)});
    }
    return soup;
}

template <typename S>
bool box_contains(canopy::basic_aabb<S> const& outer, canopy::basic_aabb<S> const& inner) {
    for (int a = 0; a < 3; ++a)
        if (!(outer.min[a] <= inner.min[a] && inner.max[a] <= outer.max[a])) return false;
    return true;
}

bool same_vertices(triangle const& a, triangle const& b) {
    auto const eq = [](vec3<float> p, vec3<float> q) { return p.x == q.x && p.y == q.y && p.z == q.z; };
    return eq(a.v0, b.v0) && eq(a.v1, b.v1) && eq(a.v2, b.v2);
}

// The primitives of one leaf (a wide-node slot: index, count), each with a key
// that names it once in the whole BVH: its position in `primitives`, or, for triangle BVHs, whose
// triangles live in blocks, its prim_id (the builder numbers them 0 … n-1). Returns false when
// the leaf points outside the storage.
template <typename Prim, typename F>
bool visit_leaf(canopy::bvh<Prim> const& b, std::uint32_t index, std::uint32_t count, F&& f) {
    if constexpr (canopy::stores_triangle_blocks_v<Prim>) {
        std::size_t const blocks = (count + canopy::triangle_block_width - 1) / canopy::triangle_block_width;
        if (std::size_t(index) + blocks > b.blocks.size()) return false;
        canopy::for_each_leaf_primitive(b, index, count, [&](Prim const& p) { f(std::size_t(p.prim_id), p); });
    } else {
        if (std::size_t(index) + count > b.primitives.size()) return false;
        for (std::uint32_t i = index; i < index + count; ++i) f(std::size_t(i), b.primitives[i]);
    }
    return true;
}

// What an independent walk of the 8-wide tree (the layout traversal uses) finds.
struct walk_result {
    std::size_t nodes_reached = 0;        // wide nodes
    std::size_t leaves = 0;
    std::size_t references = 0;           // primitives in the leaves
    std::size_t max_leaf = 0;
    int levels = 0;                       // wide node levels on the deepest path
    std::vector<int> primitive_owners;    // how many leaves own each stored primitive
    bool structure_ok = true;             // indices in range, each node reached once, used slots first
    bool unused_ok = true;                // unused slots: empty box, count 0, child invalid_id
    bool bounds_ok = true;                // a slot's box holds its leaf's primitives or its node's slots
    canopy::aabb root_union;              // union of the root's slot boxes
    double sah_cost = 0;                  // Σ area/area(root) · (traversal per wide node, count · intersection per leaf)
};

// Depth first from node 0 of `count` nodes: visit(node, push) for each node reached once, push(child)
// stacking a child one level down. A node out of range or reached twice clears w.structure_ok;
// w.nodes_reached and w.levels count what was reached.
template <typename Walk, typename Visit>
void walk_nodes(std::size_t count, Walk& w, Visit&& visit) {
    if (count == 0) return;
    std::vector<int> reached(count, 0);
    struct item {
        std::uint32_t node;
        int level;
    };
    std::vector<item> stack{{0, 1}};
    while (!stack.empty()) {
        item const it = stack.back();
        stack.pop_back();
        if (it.node >= count || reached[it.node]++) {
            w.structure_ok = false;
            continue;
        }
        ++w.nodes_reached;
        w.levels = std::max(w.levels, it.level);
        visit(it.node, [&](std::uint32_t child) { stack.push_back({child, it.level + 1}); });
    }
}

// The `count` primitives of a leaf from `index`: each counted in w.primitive_owners, and
// bounds_ok cleared unless `box` holds it; an index out of range clears w.structure_ok.
template <typename Prim, typename Walk>
void own_leaf(canopy::bvh<Prim> const& b, std::uint32_t index, std::uint32_t count, canopy::aabb const& box, Walk& w,
              bool& bounds_ok) {
    bool const in_range = visit_leaf(b, index, count, [&](std::size_t key, Prim const& p) {
        if (key >= w.primitive_owners.size()) {
            w.structure_ok = false;
            return;
        }
        ++w.primitive_owners[key];
        bounds_ok = bounds_ok && box_contains(box, get_bounds(p));
    });
    if (!in_range) w.structure_ok = false;
}

template <typename Prim>
walk_result walk(canopy::bvh<Prim> const& b, canopy::sah_costs costs = {}) {
    walk_result w;
    w.primitive_owners.assign(b.primitive_count(), 0);
    if (b.wide_nodes.empty()) return w;
    double const root_area = double(surface_area(b.bounds()));
    auto const rel = [&](canopy::aabb const& box) { return root_area > 0 ? double(surface_area(box)) / root_area : 1.0; };
    w.sah_cost = rel(b.bounds()) * double(costs.traversal);
    walk_nodes(b.wide_nodes.size(), w, [&](std::uint32_t index, auto&& push) {
        auto const& node = b.wide_nodes[index];
        bool seen_unused = false;
        for (int i = 0; i < canopy::bvh_width; ++i) {
            auto const k = std::size_t(i);
            auto const box = node.child_bounds(i);
            if (index == 0) w.root_union = extend(w.root_union, box);
            if (!node.used(i)) {
                seen_unused = true;
                w.unused_ok = w.unused_ok && node.count[k] == 0 && canopy::is_empty(box);
                continue;
            }
            w.structure_ok = w.structure_ok && !seen_unused;
            if (node.count[k] > 0) {
                ++w.leaves;
                w.references += node.count[k];
                w.max_leaf = std::max<std::size_t>(w.max_leaf, node.count[k]);
                w.sah_cost += rel(box) * double(costs.intersection) * double(node.count[k]);
                own_leaf(b, node.child[k], node.count[k], box, w, w.bounds_ok);
            } else {
                w.sah_cost += rel(box) * double(costs.traversal);
                if (node.child[k] >= b.wide_nodes.size()) {
                    w.structure_ok = false;
                    continue;
                }
                // Children after their parents: refit's one reverse sweep relies on it.
                w.structure_ok = w.structure_ok && node.child[k] > index;
                auto const& child = b.wide_nodes[node.child[k]];
                for (int j = 0; j < canopy::bvh_width; ++j)
                    if (child.used(j)) w.bounds_ok = w.bounds_ok && box_contains(box, child.child_bounds(j));
                push(node.child[k]);
            }
        }
    });
    return w;
}

// The wide tree is well formed, reached whole, no deeper than b.depth, its root box the union of
// the root's slots, and every primitive in exactly one leaf.
template <typename Prim>
void check_wide_tree(canopy::bvh<Prim> const& b) {
    walk_result const w = walk(b);
    CHECK(w.structure_ok);
    CHECK(w.unused_ok);
    CHECK(w.bounds_ok);
    CHECK(w.nodes_reached == b.wide_nodes.size());
    CHECK(std::all_of(w.primitive_owners.begin(), w.primitive_owners.end(), [](int n) { return n == 1; }));
    CHECK(w.levels <= b.depth);
    CHECK(box_contains(w.root_union, b.bounds()));
    CHECK(box_contains(b.bounds(), w.root_union));
}

// The full builder contract for an input whose centroids are distinct.
void check_build_contract(std::vector<triangle> const& input, mesh_bvh const& b, canopy::bvh_build_options const& options) {
    REQUIRE(b.primitive_count() == input.size());
    // prim_id = index in the input; each input primitive appears exactly once, unchanged.
    std::vector<int> seen(input.size(), 0);
    bool ids_ok = true;
    canopy::for_each_primitive(b, [&](triangle const& p) {
        if (p.prim_id >= input.size()) {
            ids_ok = false;
            return;
        }
        ++seen[p.prim_id];
        ids_ok = ids_ok && same_vertices(p, input[p.prim_id]) && p.geom_id == input[p.prim_id].geom_id;
    });
    CHECK(ids_ok);
    CHECK(std::all_of(seen.begin(), seen.end(), [](int n) { return n == 1; }));

    walk_result const w = walk(b);
    CHECK(b.depth <= options.max_depth);
    // The default leaf size of triangle BVHs is one block of triangles.
    int const max_leaf = options.max_leaf_size != 0 ? options.max_leaf_size : canopy::triangle_block_width;
    CHECK(w.max_leaf <= std::size_t(max_leaf));
    CHECK(w.references == input.size());
    // The root box is the union of the primitives' boxes.
    canopy::aabb all;
    for (auto const& p : input) all = extend(all, get_bounds(p));
    CHECK(box_contains(b.bounds(), all));
    CHECK(box_contains(all, b.bounds()));
    check_wide_tree(b);
}

} // namespace

TEST_CASE("build_binned_sah keeps every primitive once, numbers them by input index, and bounds them") {
    random_source rng(1);
    auto const soup = soup_to_renumber(rng, 2000, 10.0f, 1.0f);
    std::vector<canopy::bvh_build_options> const variants{
        {},
        {.max_leaf_size = 1},
        {.max_leaf_size = 8, .bins = 2},
        {.max_leaf_size = 2, .bins = 256, .costs = {.traversal = 0.25f, .intersection = 2.0f}},
        {.max_leaf_size = 4, .bins = 16, .parallel_threshold = 16},   // parallel subtree builds
        {.max_leaf_size = 4, .bins = 8, .costs = {.traversal = 10.0f, .intersection = 1.0f}},
    };
    for (std::size_t i = 0; i < variants.size(); ++i) {
        INFO("options #" << i);
        mesh_bvh const b = canopy::build_binned_sah(soup, variants[i]);
        check_build_contract(soup, b, variants[i]);
    }
}

TEST_CASE("build_binned_sah respects max_depth, where leaves may exceed max_leaf_size") {
    random_source rng(2);
    auto const soup = soup_to_renumber(rng, 500, 10.0f, 1.0f);
    for (int max_depth : {1, 2, 3, 6}) {
        INFO("max_depth " << max_depth);
        canopy::bvh_build_options const options{.max_leaf_size = 2, .max_depth = max_depth};
        mesh_bvh const b = canopy::build_binned_sah(soup, options);
        walk_result const w = walk(b);
        CHECK(b.depth <= max_depth);
        // One binary level: the root is a leaf, the one slot of one wide node.
        if (max_depth == 1) CHECK((b.wide_nodes.size() == 1 && w.leaves == 1));
        check_wide_tree(b);
    }
    // The default depth limit is met by a deep input too (a geometric progression of sizes).
    std::vector<triangle> nested;
    for (int i = 0; i < 300; ++i) {
        float const x = std::ldexp(1.0f, -i / 3);
        nested.push_back({{x, 0, 0}, {x, x, 0}, {x, 0, x}});
    }
    mesh_bvh const deep = canopy::build_binned_sah(nested, {.max_leaf_size = 1});
    CHECK(deep.depth <= canopy::bvh_max_depth);
    CHECK(walk(deep).structure_ok);
}

TEST_CASE("an empty input gives an empty BVH, and queries on it miss") {
    std::vector<triangle> const none;
    mesh_bvh const b = canopy::build_binned_sah(none);
    CHECK(b.empty());
    CHECK(b.wide_nodes.empty());
    CHECK(b.root_bounds.empty());
    CHECK(b.primitive_count() == 0);
    CHECK(b.blocks.empty());
    CHECK(canopy::is_empty(b.bounds()));
    auto const s = canopy::compute_stats(b);
    CHECK(s.node_count == 0);
    CHECK(s.leaf_count == 0);
    CHECK(s.primitive_count == 0);
    CHECK(s.bytes == 0);
    ray const r{{0, 0, -5}, 0, {0, 0, 1}, inf};
    CHECK_FALSE(canopy::closest_hit(r, &b, &b + 1).hit);
    CHECK_FALSE(canopy::any_hit(r, &b, &b + 1).hit);
    CHECK_FALSE(canopy::multi_hit<3>(r, &b, &b + 1)[0].hit);
    CHECK_FALSE(canopy::intersect(r, b).hit);
    CHECK_FALSE(canopy::closest_hit(r, none.begin(), none.end()).hit);
    // An instance of an empty BVH, inside a BVH: empty bounds, no hit.
    std::vector<canopy::instance<mesh_bvh>> const inst{canopy::instance<mesh_bvh>(b, canopy::affine_transform<float>::identity(), 3)};
    CHECK(canopy::is_empty(get_bounds(inst[0])));
    auto const top = canopy::build_binned_sah(inst);
    CHECK_FALSE(canopy::closest_hit(r, &top, &top + 1).hit);
    CHECK_FALSE(canopy::any_hit(r, inst.begin(), inst.end()).hit);
}

TEST_CASE("compute_stats is consistent with the tree") {
    random_source rng(3);
    auto const soup = soup_to_renumber(rng, 1000, 10.0f, 1.0f);
    for (int leaf : {1, 4, 8}) {
        mesh_bvh const b = canopy::build_binned_sah(soup, {.max_leaf_size = leaf});
        canopy::sah_costs const costs{.traversal = 1.5f, .intersection = 0.5f};
        auto const s = canopy::compute_stats(b, costs);
        walk_result const w = walk(b, costs);
        INFO("max_leaf_size " << leaf);
        CHECK(s.node_count == b.wide_nodes.size() + w.leaves);
        CHECK(s.leaf_count == w.leaves);
        CHECK(s.reference_count == soup.size());
        CHECK(s.primitive_count == soup.size());
        CHECK(s.depth == b.depth);
        CHECK(s.max_leaf_size == w.max_leaf);
        CHECK(s.max_leaf_size <= std::size_t(leaf));
        CHECK(s.wide_node_count == b.wide_nodes.size());
        CHECK(s.bytes == sizeof(canopy::aabb) + b.wide_nodes.size() * sizeof(canopy::wide_bvh_node<float>) +
                             b.blocks.size() * sizeof(canopy::triangle_block));
        CHECK(s.bytes_per_primitive == Approx(double(s.bytes) / double(soup.size())));
        CHECK(s.sah_cost == Approx(w.sah_cost).epsilon(1e-9));
        // At least the root's traversal, at most testing everything at every level.
        CHECK(s.sah_cost >= costs.traversal);
        CHECK(s.sah_cost <= double(costs.traversal) * double(s.node_count) + double(costs.intersection) * double(soup.size()) * (b.depth + 1));
    }
    // A single primitive: one leaf, depth 1.
    mesh_bvh const single = canopy::build_binned_sah(std::vector<triangle>{triangle{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, 9}});
    auto const s = canopy::compute_stats(single);
    CHECK(s.node_count == 2); // one wide node, one leaf
    CHECK(s.leaf_count == 1);
    CHECK(s.depth == 1);
    CHECK(single.blocks[0].prim_id[0] == 0u);
}

TEST_CASE("coincident centroids build without crashing and split by index") {
    // 300 copies of one triangle: every centroid coincides.
    std::vector<triangle> const copies(300, triangle{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, 0, 5});
    mesh_bvh const b = canopy::build_binned_sah(copies, {.max_leaf_size = 4});
    walk_result const w = walk(b);
    CHECK(w.structure_ok);
    CHECK(std::all_of(w.primitive_owners.begin(), w.primitive_owners.end(), [](int n) { return n == 1; }));
    CHECK(w.max_leaf <= 4);
    CHECK(b.depth <= canopy::bvh_max_depth);
    check_wide_tree(b);
    std::vector<int> seen(copies.size(), 0);
    canopy::for_each_primitive(b, [&](triangle const& p) { ++seen[p.prim_id]; });
    CHECK(std::all_of(seen.begin(), seen.end(), [](int n) { return n == 1; }));
    // All copies are hit at the same t: the smallest prim_id wins, multi_hit lists them in order.
    ray const r{{0.25f, 0.25f, 3}, 0, {0, 0, -1}, inf};
    auto const hr = canopy::closest_hit(r, &b, &b + 1);
    REQUIRE(hr.hit);
    CHECK(hr.prim_id == 0u);
    CHECK(hr.t == 3.0f);
    auto const many = canopy::multi_hit<5>(r, &b, &b + 1);
    for (std::uint32_t i = 0; i < 5; ++i) {
        CHECK(many[i].hit);
        CHECK(many[i].prim_id == i);
    }
    // Half the copies elsewhere: two clusters of coincident centroids.
    std::vector<triangle> two = copies;
    for (std::size_t i = 0; i < two.size(); i += 2) two[i].v0.z = two[i].v1.z = two[i].v2.z = 1;
    check_build_contract(two, canopy::build_binned_sah(two, {}), {});
}

TEST_CASE("non-finite vertices do not crash the builder") {
    random_source rng(4);
    auto soup = soup_to_renumber(rng, 200, 5.0f, 1.0f);
    soup[3].v1.x = std::numeric_limits<float>::quiet_NaN();
    soup[50].v2 = vec3<float>(std::numeric_limits<float>::quiet_NaN());
    soup[51].v0.y = inf;
    mesh_bvh const b = canopy::build_binned_sah(soup);
    walk_result const w = walk(b);
    CHECK(w.structure_ok);
    CHECK(std::all_of(w.primitive_owners.begin(), w.primitive_owners.end(), [](int n) { return n == 1; }));
    std::vector<int> seen(soup.size(), 0);
    canopy::for_each_primitive(b, [&](triangle const& p) { ++seen[p.prim_id]; });
    CHECK(std::all_of(seen.begin(), seen.end(), [](int n) { return n == 1; }));
}

TEST_CASE("BVHs over spheres and over BVHs satisfy the same contract") {
    random_source rng(5);
    std::vector<canopy::sphere> spheres;
    for (int i = 0; i < 700; ++i) spheres.push_back({rng.point(-10, 10), rng.uniform(0.05f, 1.0f)});
    auto const b = canopy::build_binned_sah(spheres);
    walk_result const w = walk(b);
    CHECK(w.structure_ok);
    CHECK(w.bounds_ok);
    CHECK(w.max_leaf <= 4);
    std::vector<int> seen(spheres.size(), 0);
    for (auto const& p : b.primitives) ++seen[p.prim_id];
    CHECK(std::all_of(seen.begin(), seen.end(), [](int n) { return n == 1; }));
    check_wide_tree(b);

    std::vector<mesh_bvh> parts;
    for (int k = 0; k < 5; ++k) parts.push_back(canopy::build_binned_sah(soup_to_renumber(rng, 100, 3.0f, 0.5f)));
    auto const roots = canopy::build_binned_sah(parts);
    walk_result const wr = walk(roots);
    CHECK(wr.structure_ok);
    CHECK(wr.bounds_ok);
    CHECK(roots.primitives.size() == 5);
    check_wide_tree(roots);
}

TEST_CASE("instance bounds hold the transformed geometry") {
    random_source rng(6);
    auto const soup = soup_to_renumber(rng, 300, 2.0f, 0.5f);
    mesh_bvh const b = canopy::build_binned_sah(soup);
    using mesh_instance = canopy::instance<mesh_bvh>;
    CHECK(canopy::instance_nesting_v<triangle> == 0);
    CHECK(canopy::instance_nesting_v<mesh_instance> == 1);
    CHECK(canopy::instance_nesting_v<canopy::instance<canopy::bvh<mesh_instance>>> == 2);

    // Identity: the BVH's own bounds.
    mesh_instance const id(b, canopy::affine_transform<float>::identity(), 1);
    auto const ib = get_bounds(id);
    CHECK(box_contains(ib, b.bounds()));
    CHECK(box_contains(b.bounds(), ib));

    for (int k = 0; k < 20; ++k) {
        std::array<float, 12> rows{};
        for (auto& x : rows) x = rng.uniform(-2, 2);
        auto const xf = canopy::affine_transform<float>::from_rows(rows);
        mesh_instance const inst(b, xf, std::uint32_t(k));
        auto const box = get_bounds(inst);
        // Every vertex, transformed exactly (long double), lies in the instance's box.
        bool inside = true;
        for (auto const& tri : soup) {
            for (vec3<float> const p : {tri.v0, tri.v1, tri.v2}) {
                for (int row = 0; row < 3; ++row) {
                    long double const x = (long double)rows[std::size_t(4 * row)] * p.x +
                                          (long double)rows[std::size_t(4 * row + 1)] * p.y +
                                          (long double)rows[std::size_t(4 * row + 2)] * p.z + rows[std::size_t(4 * row + 3)];
                    inside = inside && box.min[row] <= x && x <= box.max[row];
                }
            }
        }
        CHECK(inside);
        CHECK_FALSE(canopy::is_empty(box));
    }
}

// Whether any used slot of b's wide nodes has a subnormal plane.
template <typename Prim>
bool has_subnormal_plane(canopy::bvh<Prim> const& b) {
    for (auto const& node : b.wide_nodes)
        for (int i = 0; i < canopy::bvh_width; ++i) {
            if (!node.used(i)) continue;
            auto const box = node.child_bounds(i);
            for (int a = 0; a < 3; ++a)
                if (std::fpclassify(box.min[a]) == FP_SUBNORMAL || std::fpclassify(box.max[a]) == FP_SUBNORMAL)
                    return true;
        }
    return false;
}

TEST_CASE("wide nodes round subnormal box sides outward, so that node tests never read a subnormal") {
    using node = canopy::wide_bvh_node<float>;
    float const smallest = std::numeric_limits<float>::min(), sub = std::numeric_limits<float>::denorm_min();
    // By hand: a lower side goes down, an upper side up, to 0 or to ±smallest normal.
    CHECK(node::outward_from_subnormal(3 * sub, false) == 0.0f);
    CHECK(node::outward_from_subnormal(3 * sub, true) == smallest);
    CHECK(node::outward_from_subnormal(-3 * sub, false) == -smallest);
    CHECK(node::outward_from_subnormal(-3 * sub, true) == 0.0f);
    CHECK(node::outward_from_subnormal(smallest / 2, true) == smallest);
    for (float const x : {0.0f, -0.0f, smallest, -smallest, 1.5f, -2e-30f, inf, -inf})
        for (bool const up : {false, true}) {
            float const y = node::outward_from_subnormal(x, up);
            CHECK(std::memcmp(&x, &y, sizeof x) == 0);
        }
    CHECK(std::isnan(node::outward_from_subnormal(std::numeric_limits<float>::quiet_NaN(), true)));

    // Triangles with subnormal coordinates: their leaves' boxes still hold them, with no subnormal
    // plane, and rays find what brute force finds.
    random_source rng(61);
    std::vector<triangle> tiny;
    for (int i = 0; i < 64; ++i) {
        float const x = float(i % 8) - 4.0f, z = float(i / 8) - 4.0f;
        float const y = (i % 3 == 0 ? 1.0f : -1.0f) * float(1 + i % 5) * 1e-40f; // subnormal heights
        tiny.push_back({{x, y, z}, {x + 1.0f, -y, z}, {x, y, z + 1.0f}, 0, 0});
    }
    mesh_bvh const flat = canopy::build_binned_sah(tiny);
    canopy::aabb input_box;
    for (auto const& t : tiny) input_box = extend(input_box, get_bounds(t));
    REQUIRE(std::fpclassify(input_box.min.y) == FP_SUBNORMAL);
    CHECK_FALSE(has_subnormal_plane(flat));
    check_wide_tree(flat);
    for (int k = 0; k < 200; ++k) {
        ray r{rng.point(-4.0f, 4.0f) + vec3<float>(0.0f, 3.0f, 0.0f), 0.0f, vec3<float>(0.0f, -1.0f, 0.0f) + rng.point(-0.2f, 0.2f), inf};
        canopy::basic_hit_record<float> best;
        for (auto const& t : tiny) {
            auto const h = canopy::intersect(r, t);
            if (h.hit && (!best.hit || h.t < best.t)) best = h;
        }
        auto const hr = canopy::closest_hit(r, &flat, &flat + 1);
        CHECK(hr.hit == best.hit);
        if (hr.hit && best.hit) CHECK(hr.t == best.t);
    }

    // Trees standing on y = 0, placed by instances: transform_box widens each instance's world box
    // by subnormals for products that underflow (min.y = -3 denorm_min), which the instances'
    // BVH must not store.
    std::vector<triangle> tree;
    for (int i = 0; i < 16; ++i) {
        float const a = float(i) * 0.4f;
        tree.push_back({{std::cos(a), 0.0f, std::sin(a)}, {0.0f, 2.0f, 0.0f}, {std::cos(a + 0.4f), 0.0f, std::sin(a + 0.4f)}, 0, 0});
    }
    mesh_bvh const mesh = canopy::build_binned_sah(tree);
    std::vector<test_support::mesh_instance> placed;
    for (int i = 0; i < 40; ++i) {
        float const angle = rng.uniform(0.0f, 6.0f), s = rng.uniform(0.7f, 1.3f);
        float const c = s * std::cos(angle), n = s * std::sin(angle);
        auto const xf = canopy::affine_transform<float>::from_rows(
            {c, 0, n, 5.0f * float(i % 8), 0, s, 0, 0, -n, 0, c, 5.0f * float(i / 8)});
        placed.emplace_back(mesh, xf, std::uint32_t(i));
    }
    REQUIRE(std::fpclassify(get_bounds(placed[0]).min.y) == FP_SUBNORMAL);
    canopy::bvh<test_support::mesh_instance> const forest = canopy::build_binned_sah(placed);
    CHECK_FALSE(has_subnormal_plane(forest));
    check_wide_tree(forest);
    for (int k = 0; k < 200; ++k) {
        ray r{vec3<float>(rng.uniform(-2.0f, 37.0f), 1.0f, -10.0f), 0.0f,
              vec3<float>(rng.uniform(-0.3f, 0.3f), rng.uniform(-0.15f, 0.05f), 1.0f), inf};
        auto const expected = test_support::instanced_brute_force_hits(r, placed, tree);
        auto const hr = canopy::closest_hit(r, &forest, &forest + 1);
        REQUIRE(hr.hit == !expected.empty());
        if (hr.hit) CHECK(hr.t == expected.front().t);
    }
}

// ---------------------------------------------------------------------------------------------
// build_quality::high (spatial splits): a triangle may be referenced from several leaves, each
// leaf box bounding only its part of it.

namespace {

// Points of a triangle, in double (exact for the vertices and the edge midpoints, within 2^-50 or
// so of the triangle for the others): its vertices, edge points and interior points.
std::vector<vec3<double>> points_of(triangle const& t, random_source& rng) {
    vec3<double> const a(t.v0), b(t.v1), c(t.v2);
    std::vector<vec3<double>> out{a, b, c, (a + b) * 0.5, (b + c) * 0.5, (c + a) * 0.5};
    for (int k = 0; k < 12; ++k) {
        double u = rng.uniform_double(0, 1), v = rng.uniform_double(0, 1);
        if (u + v > 1) u = 1 - u, v = 1 - v;
        if (k < 3) v = 0; // on an edge
        out.push_back(a + (b - a) * u + (c - a) * v);
    }
    return out;
}

// The contract of a build at high quality: the tree is well formed, every input triangle is
// referenced by one leaf or more (never twice by one leaf), stored whole with prim_id = its input
// index, and the boxes of the leaves that reference it cover it. Returns the number of references.
std::size_t check_split_build(std::vector<triangle> const& input, mesh_bvh const& b, float budget, random_source& rng) {
    REQUIRE(b.primitive_count() == input.size());
    // The wide tree: well formed, every triangle in one of its leaves or more (a leaf's box may
    // bound only a clipped piece of a triangle, so it need not hold the triangle's box).
    walk_result const w = walk(b);
    CHECK(w.structure_ok);
    CHECK(w.unused_ok);
    CHECK(w.nodes_reached == b.wide_nodes.size());
    CHECK(w.levels <= b.depth);
    CHECK(std::all_of(w.primitive_owners.begin(), w.primitive_owners.end(), [](int n) { return n >= 1; }));
    CHECK(box_contains(w.root_union, b.bounds()));
    CHECK(box_contains(b.bounds(), w.root_union));
    std::vector<std::vector<canopy::aabb>> leaf_boxes(input.size());
    std::size_t references = 0;
    bool ids_ok = true, once_per_leaf = true;
    canopy::for_each_leaf(b, [&](std::uint32_t child, std::uint32_t count, canopy::aabb const& leaf_box) {
        std::vector<std::uint32_t> in_leaf;
        canopy::for_each_leaf_primitive(b, child, count, [&](triangle const& p) {
            ++references;
            if (p.prim_id >= input.size()) {
                ids_ok = false;
                return;
            }
            ids_ok = ids_ok && same_vertices(p, input[p.prim_id]) && p.geom_id == input[p.prim_id].geom_id;
            once_per_leaf = once_per_leaf && std::find(in_leaf.begin(), in_leaf.end(), p.prim_id) == in_leaf.end();
            in_leaf.push_back(p.prim_id);
            leaf_boxes[p.prim_id].push_back(leaf_box);
        });
    });
    CHECK(w.references == references);
    CHECK(ids_ok);
    CHECK(once_per_leaf);
    CHECK(references <= input.size() + std::size_t(double(input.size()) * double(budget)));
    std::size_t uncovered = 0, unreferenced = 0;
    for (std::size_t i = 0; i < input.size(); ++i) {
        unreferenced += leaf_boxes[i].empty();
        for (vec3<double> const& p : points_of(input[i], rng)) {
            double const tolerance = 1e-13 * (1.0 + std::max({std::abs(p.x), std::abs(p.y), std::abs(p.z)}));
            bool const inside = std::any_of(leaf_boxes[i].begin(), leaf_boxes[i].end(), [&](canopy::aabb const& box) {
                for (int a = 0; a < 3; ++a)
                    if (!(double(box.min[a]) - tolerance <= p[a] && p[a] <= double(box.max[a]) + tolerance)) return false;
                return true;
            });
            uncovered += !inside;
        }
    }
    CHECK(unreferenced == 0);
    CHECK(uncovered == 0);
    return references;
}

} // namespace

TEST_CASE("build_quality::high references every triangle whole, by input index, from leaves whose boxes cover it") {
    random_source rng(71);
    // Long thin random triangles, prim_id deliberately wrong: the builder must renumber.
    auto needles = test_support::needle_soup(rng, 1500, 5.0f, 0.01f);
    for (auto& t : needles) t.prim_id = 777;
    std::vector<std::pair<char const*, std::vector<triangle>>> const inputs{{"slivers", test_support::sliver_mesh()},
                                                                           {"needles", needles}};
    for (auto const& [name, input] : inputs) {
        for (canopy::bvh_build_options const& options :
             {canopy::bvh_build_options{.quality = canopy::build_quality::high},
              canopy::bvh_build_options{.max_leaf_size = 1, .bins = 8, .quality = canopy::build_quality::high},
              canopy::bvh_build_options{.quality = canopy::build_quality::high, .split_budget = 2.0f},
              canopy::bvh_build_options{.quality = canopy::build_quality::high, .split_min_references = 1}}) {
            INFO(name << ", max_leaf_size " << options.max_leaf_size << ", split budget " << options.split_budget
                      << ", split_min_references " << options.split_min_references);
            mesh_bvh const high = canopy::build_binned_sah(input, options);
            std::size_t const references = check_split_build(input, high, options.split_budget, rng);
            CHECK(references > input.size() + input.size() / 20); // spatial splits did happen
            // The SAH cost falls below the object-split build's.
            auto fast = options;
            fast.quality = canopy::build_quality::fast;
            CHECK(canopy::compute_stats(high).sah_cost < canopy::compute_stats(canopy::build_binned_sah(input, fast)).sah_cost);
        }
    }
    // No budget: no reference is added.
    auto const slivers = test_support::sliver_mesh();
    mesh_bvh const none = canopy::build_binned_sah(slivers, {.quality = canopy::build_quality::high, .split_budget = 0.0f});
    CHECK(check_split_build(slivers, none, 0.0f, rng) == slivers.size());
}

namespace {

// Whether two BVHs are the same tree: node for node in depth-first order the same boxes and
// counts, leaf for leaf the same triangles in the same order (the nodes' and leaves' positions in
// their arrays may differ: they follow the order in which threads finished).
template <typename Prim>
bool same_tree(canopy::bvh<Prim> const& a, canopy::bvh<Prim> const& b, std::uint32_t i = 0, std::uint32_t j = 0) {
    if (a.empty() || b.empty()) return a.empty() && b.empty();
    if (i == 0 && j == 0) {
        auto const ra = a.bounds(), rb = b.bounds();
        if (std::memcmp(&ra, &rb, sizeof ra) != 0) return false;
    }
    auto const& x = a.wide_nodes[i];
    auto const& y = b.wide_nodes[j];
    if (std::memcmp(&x.planes, &y.planes, sizeof x.planes) != 0 || x.count != y.count) return false;
    for (int k = 0; k < canopy::bvh_width; ++k) {
        auto const slot = std::size_t(k);
        if (x.used(k) != y.used(k)) return false;
        if (!x.used(k)) continue;
        if (x.count[slot] == 0) {
            if (!same_tree(a, b, x.child[slot], y.child[slot])) return false;
            continue;
        }
        std::vector<std::uint32_t> ids_a, ids_b;
        canopy::for_each_leaf_primitive(a, x.child[slot], x.count[slot], [&](Prim const& t) { ids_a.push_back(t.prim_id); });
        canopy::for_each_leaf_primitive(b, y.child[slot], y.count[slot], [&](Prim const& t) { ids_b.push_back(t.prim_id); });
        if (ids_a != ids_b) return false;
    }
    return true;
}

} // namespace

TEST_CASE("the same tree on one thread and on two, whatever the parallel threshold, at both qualities") {
    random_source rng(72);
    std::vector<std::pair<char const*, std::vector<triangle>>> const inputs{
        {"slivers", test_support::sliver_mesh()}, {"needles", test_support::needle_soup(rng, 3000, 5.0f, 0.01f)}};
    for (auto const& [name, input] : inputs) {
        for (auto const quality : {canopy::build_quality::fast, canopy::build_quality::high}) {
            INFO(name << (quality == canopy::build_quality::high ? ", high" : ", fast"));
            // parallel_threshold 16: subtrees of 16 references and more are tasks, and the
            // object bins (fast) or spatial bins (high) of nodes of parallel_binning_min (1,024)
            // references and more are filled in chunks (bin_chunk: the 3,000 needles' root in 64
            // chunks of 47), in parallel.
            auto const build = [&](std::size_t threads, std::size_t threshold) {
                tbb::global_control const limit(tbb::global_control::max_allowed_parallelism, threads);
                return canopy::build_binned_sah(input, {.parallel_threshold = threshold, .quality = quality});
            };
            mesh_bvh const one = build(1, 16);
            CHECK(same_tree(one, build(2, 16)));
            CHECK(same_tree(one, build(2, 16)));
            CHECK(same_tree(one, build(1, std::size_t(1) << 30))); // no task, no chunk
            // parallel_threshold 1: every node a task; at most max_bin_chunks chunks per node.
            CHECK(same_tree(one, build(2, 1)));
        }
    }
    // Double-precision triangles take the scalar binning: the same, with chunks and without.
    std::vector<canopy::basic_triangle<double>> slivers;
    for (auto const& t : test_support::sliver_mesh())
        slivers.push_back({vec3<double>(t.v0), vec3<double>(t.v1), vec3<double>(t.v2)});
    auto const build = [&](std::size_t threshold) {
        return canopy::build_binned_sah(slivers, {.parallel_threshold = threshold, .quality = canopy::build_quality::high});
    };
    auto const chunked = build(16), whole = build(std::size_t(1) << 30);
    CHECK(canopy::compute_stats(chunked).reference_count > slivers.size()); // spatial splits did happen
    CHECK(same_tree(chunked, whole));
}

TEST_CASE("split_min_gain: no spatial split where none could gain enough, the sliver mesh's tree unchanged") {
    random_source rng(73);
    auto const slivers = test_support::sliver_mesh();
    // Gains are fractions of an area, never above 1: nothing is split, every triangle referenced once.
    canopy::bvh_build_options const never{.quality = canopy::build_quality::high, .split_min_gain = 1.0f};
    mesh_bvh const unsplit = canopy::build_binned_sah(slivers, never);
    CHECK(check_split_build(slivers, unsplit, 0.3f, rng) == slivers.size());
    // The slivers' splits all gain far more than the default's 3 %: the default builds the tree
    // that the test turned off (0) builds.
    mesh_bvh const gated = canopy::build_binned_sah(slivers, {.quality = canopy::build_quality::high});
    mesh_bvh const ungated = canopy::build_binned_sah(slivers, {.quality = canopy::build_quality::high, .split_min_gain = 0.0f});
    CHECK(canopy::compute_stats(gated).reference_count > slivers.size() + slivers.size() / 20);
    CHECK(same_tree(gated, ungated));
}

TEST_CASE("split_min_references: no spatial split in nodes with fewer references") {
    random_source rng(79);
    auto const slivers = test_support::sliver_mesh();
    // A threshold above the triangle count: no node may split, every triangle is referenced once.
    mesh_bvh const unsplit = canopy::build_binned_sah(
        slivers, {.quality = canopy::build_quality::high, .split_min_references = std::uint32_t(slivers.size() + 1)});
    CHECK(check_split_build(slivers, unsplit, 0.3f, rng) == slivers.size());
}

TEST_CASE("a build's phase times are each non-negative and together within the build's own time") {
    random_source rng(11);
    auto const soup = soup_to_renumber(rng, 20000, 20.0f, 1.0f);
    for (auto const quality : {canopy::build_quality::fast, canopy::build_quality::high}) {
        INFO((quality == canopy::build_quality::high ? "high" : "fast"));
        auto const start = std::chrono::steady_clock::now();
        mesh_bvh const b = canopy::build_binned_sah(soup, {.quality = quality});
        double const elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        auto const& p = b.build_phases;
        CHECK(p.references >= 0.0);
        CHECK(p.tree > 0.0);
        CHECK(p.wide_nodes >= 0.0);
        CHECK(p.leaves > 0.0);
        CHECK(p.total() <= elapsed);
    }
    CHECK(mesh_bvh{}.build_phases.total() == 0.0);
    std::vector<triangle> const none;
    CHECK(canopy::build_binned_sah(none).build_phases.total() == 0.0);
}

TEST_CASE("a BVH's large arrays start on 2 MiB boundaries, and a copy of a BVH holds the same tree and blocks") {
    constexpr std::uintptr_t huge_page = std::uintptr_t(2) << 20;
    // large_array_allocator on its own: 3 MiB aligned, 1 KiB as std::allocator gives it.
    canopy::large_array_allocator<float> floats;
    float* const large = floats.allocate((3u << 20) / sizeof(float));
    CHECK(reinterpret_cast<std::uintptr_t>(large) % huge_page == 0);
    large[0] = 1.0f;
    large[(3u << 20) / sizeof(float) - 1] = 2.0f;
    floats.deallocate(large, (3u << 20) / sizeof(float));
    float* const small = floats.allocate(256);
    small[255] = 3.0f;
    floats.deallocate(small, 256);

    random_source rng(7);
    auto const soup = soup_to_renumber(rng, 60000, 50.0f, 1.0f);
    mesh_bvh const b = canopy::build_binned_sah(soup, {.quality = canopy::build_quality::fast});
    std::size_t const block_bytes = b.blocks.size() * sizeof(b.blocks[0]);
    REQUIRE(block_bytes >= std::size_t(huge_page)); // the case under test
    CHECK(reinterpret_cast<std::uintptr_t>(b.blocks.data()) % huge_page == 0);
    mesh_bvh const copy = b;
    CHECK(same_tree(copy, b));
    REQUIRE(copy.blocks.size() == b.blocks.size());
    std::size_t differing = 0;
    for (std::size_t k = 0; k < b.blocks.size(); ++k)
        differing += copy.blocks[k].vertex != b.blocks[k].vertex || copy.blocks[k].prim_id != b.blocks[k].prim_id ||
                     copy.blocks[k].geom_id != b.blocks[k].geom_id || copy.blocks[k].testable != b.blocks[k].testable;
    CHECK(differing == 0);
    CHECK(reinterpret_cast<std::uintptr_t>(copy.blocks.data()) % huge_page == 0);
    check_build_contract(soup, copy, {});
}

TEST_CASE("freed large arrays are kept for the next ones that fit, within the cache's limit") {
    constexpr std::size_t mib = std::size_t(1) << 20;
    std::size_t const old_limit = canopy::memory_cache_limit();
    canopy::release_cached_memory();
    REQUIRE(canopy::cached_memory() == 0);
    canopy::large_array_allocator<std::byte> bytes;

    // Freed: kept (rounded up to whole 2 MiB pages), and given back, contents as left, to a request
    // that fits (at least as large, at most twice).
    std::byte* const a = bytes.allocate(5 * mib);
    a[0] = std::byte{42};
    bytes.deallocate(a, 5 * mib);
    CHECK(canopy::cached_memory() == 6 * mib);
    std::byte* const too_small_for = bytes.allocate(2 * mib); // 6 MiB is more than twice 2 MiB
    CHECK(too_small_for != a);
    CHECK(canopy::cached_memory() == 6 * mib);
    std::byte* const too_large_for = bytes.allocate(7 * mib);
    CHECK(too_large_for != a);
    std::byte* const reused = bytes.allocate(4 * mib);
    CHECK(reused == a);
    CHECK(reused[0] == std::byte{42});
    CHECK(canopy::cached_memory() == 0);
    reused[4 * mib - 1] = std::byte{1};

    // The best fit of several.
    bytes.deallocate(too_small_for, 2 * mib);
    bytes.deallocate(too_large_for, 7 * mib);
    bytes.deallocate(reused, 4 * mib); // its 6 MiB, not its 4
    CHECK(canopy::cached_memory() == (2 + 8 + 6) * mib);
    std::byte* const best = bytes.allocate(5 * mib + 1);
    CHECK(best == a);
    bytes.deallocate(best, 5 * mib + 1);

    // The limit: the oldest blocks go first; a block larger than the limit is never kept.
    canopy::set_memory_cache_limit(12 * mib);
    CHECK(canopy::memory_cache_limit() == 12 * mib);
    CHECK(canopy::cached_memory() <= 12 * mib);
    std::byte* const huge = bytes.allocate(13 * mib);
    bytes.deallocate(huge, 13 * mib);
    CHECK(canopy::cached_memory() <= 12 * mib);
    canopy::set_memory_cache_limit(0);
    CHECK(canopy::cached_memory() == 0);
    std::byte* const uncached = bytes.allocate(3 * mib);
    bytes.deallocate(uncached, 3 * mib);
    CHECK(canopy::cached_memory() == 0);

    // A build's arrays go back to the cache with the BVH, and the next build takes them.
    canopy::set_memory_cache_limit(old_limit);
    random_source rng(8);
    auto const soup = soup_to_renumber(rng, 60000, 50.0f, 1.0f);
    {
        mesh_bvh const first = canopy::build_binned_sah(soup, {.quality = canopy::build_quality::fast});
        REQUIRE(first.blocks.size() * sizeof(first.blocks[0]) >= 2 * mib);
    }
    std::size_t const after_first = canopy::cached_memory();
    CHECK(after_first > 0);
    mesh_bvh const second = canopy::build_binned_sah(soup, {.quality = canopy::build_quality::fast});
    CHECK(canopy::cached_memory() <= after_first);
    check_build_contract(soup, second, {});

    // A user's resize of the BVH's vector type still value-initialises, even on a block that a
    // BVH's triangles filled before (the builder alone leaves its blocks to be written whole).
    std::size_t const block_count = second.blocks.size();
    canopy::release_cached_memory();
    canopy::triangle_block const* filled = nullptr;
    {
        mesh_bvh const dropped = second;
        REQUIRE(dropped.blocks.size() == block_count);
        filled = dropped.blocks.data();
    }
    {
        std::vector<canopy::triangle_block, canopy::large_array_allocator<canopy::triangle_block>> blocks;
        blocks.resize(block_count);
        CHECK(blocks.data() == filled); // the case under test: the same memory
        std::size_t written = 0;
        for (auto const& block : blocks)
            written += block.testable != 0 || block.prim_id[0] != canopy::triangle_block::invalid_ids()[0] ||
                       block.vertex[0][0][0] != 0.0f;
        CHECK(written == 0);
    }
    CHECK(canopy::release_cached_memory() > 0);
    CHECK(canopy::cached_memory() == 0);
}

TEST_CASE("build_quality::high keeps max_depth, and never splits triangles with NaN or infinite coordinates") {
    random_source rng(72);
    auto input = test_support::sliver_mesh();
    for (int max_depth : {1, 2, 5}) {
        mesh_bvh const b = canopy::build_binned_sah(input, {.max_depth = max_depth, .quality = canopy::build_quality::high});
        CHECK(b.depth <= max_depth);
        check_split_build(input, b, 0.3f, rng);
    }
    float const nan = std::numeric_limits<float>::quiet_NaN();
    std::size_t const finite = input.size();
    input.push_back({{nan, 0, 0}, {1, 1, 1}, {2, 0, 1}, 0, 0});
    input.push_back({{-inf, 0, 0}, {inf, 1, 1}, {2, 0, 1}, 0, 0});
    input.push_back({{0, 0, 0}, {1e30f, 1e30f, 0}, {0, 1, 0}, 0, 0});
    mesh_bvh const b = canopy::build_binned_sah(input, {.quality = canopy::build_quality::high});
    REQUIRE(b.primitive_count() == input.size());
    std::vector<int> seen(input.size(), 0);
    canopy::for_each_primitive(b, [&](triangle const& p) { ++seen[p.prim_id]; });
    CHECK(std::all_of(seen.begin(), seen.end(), [](int n) { return n >= 1; }));
    CHECK(seen[finite] == 1);
    CHECK(seen[finite + 1] == 1);
}

TEST_CASE("build_quality::automatic: the sliver box share, by hand, and the quality it picks") {
    using canopy::build_quality;
    // A right triangle in the plane z = 0 with legs a and b along x and y: box half-area a·b,
    // area a·b/2 (ratio 2, not a sliver). A needle from the origin to (L, L, 0) and (L, L + w, 0):
    // box half-area L·(L + w), area L·w/2 (ratio 2(L + w)/w, a sliver for w ≪ L).
    triangle const right{{0, 0, 0}, {4, 0, 0}, {0, 2, 0}, 0, 0};   // half-area 8
    triangle const needle{{0, 0, 0}, {8, 8, 0}, {8, 8.0625f, 0}, 1, 0}; // half-area 8 · 8.0625 = 64.5, area 0.25
    std::vector<triangle> const mixed{right, needle};
    CHECK(canopy::sliver_box_share(std::span<triangle const>(std::vector<triangle>{right})) == 0.0);
    CHECK(canopy::sliver_box_share(std::span<triangle const>(std::vector<triangle>{needle})) == 1.0);
    CHECK(canopy::sliver_box_share(std::span<triangle const>(mixed)) == Approx(64.5 / (64.5 + 8.0)).epsilon(1e-12));
    CHECK(canopy::spatial_splits_pay(std::span<triangle const>(mixed)));
    // Degenerate and non-finite triangles do not count against a mesh: a zero-area triangle with a
    // zero-area box adds nothing, a NaN one is skipped.
    triangle const point{{1, 1, 1}, {1, 1, 1}, {1, 1, 1}, 2, 0};
    float const nan = std::numeric_limits<float>::quiet_NaN();
    triangle const broken{{nan, 0, 0}, {1, 0, 0}, {0, 1, 0}, 3, 0};
    CHECK(canopy::sliver_box_share(std::span<triangle const>(std::vector<triangle>{right, point, broken})) == 0.0);

    // Over many chunks (sliver_chunk triangles each, summed in parallel): the share of a mix whose
    // exact value is known, bit for bit the same on one thread and on two.
    {
        std::size_t const chunks = 5;
        std::vector<triangle> many;
        for (std::size_t i = 0; i < chunks * canopy::sliver_chunk + 3; ++i) many.push_back(i % 4 == 0 ? needle : right);
        double const needles = double((many.size() + 3) / 4), rights = double(many.size()) - needles;
        double shares[2];
        for (int threads = 1; threads <= 2; ++threads) {
            tbb::global_control const limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
            shares[threads - 1] = canopy::sliver_box_share(std::span<triangle const>(many));
        }
        CHECK(shares[0] == shares[1]);
        CHECK(shares[0] == Approx(64.5 * needles / (64.5 * needles + 8.0 * rights)).epsilon(1e-12));
    }

    // The default is automatic: well-shaped triangles build fast, slivers build high, and both
    // say so; explicit qualities are kept.
    random_source rng(77);
    std::vector<triangle> blobs, slivers;
    for (std::uint32_t i = 0; i < 2000; ++i) {
        vec3<float> const c = rng.point(-50, 50);
        blobs.push_back({c, c + vec3<float>(1, 0, 0.2f), c + vec3<float>(0.1f, 1, 0), i, 0});
        vec3<float> const d = rng.point(-1, 1) * 40.0f;
        slivers.push_back({c, c + d, c + d + vec3<float>(0, 0, 0.01f), i, 0});
    }
    CHECK(canopy::bvh_build_options{}.quality == build_quality::automatic);
    CHECK(canopy::build_binned_sah(blobs).quality == build_quality::fast);
    CHECK(canopy::build_binned_sah(slivers).quality == build_quality::high);
    CHECK(canopy::build_binned_sah(slivers, {.quality = build_quality::fast}).quality == build_quality::fast);
    CHECK(canopy::build_binned_sah(blobs, {.quality = build_quality::high}).quality == build_quality::high);
    // The automatic build of the slivers is the high build, node for node.
    auto const automatic = canopy::build_binned_sah(slivers);
    auto const high = canopy::build_binned_sah(slivers, {.quality = build_quality::high});
    CHECK(same_tree(automatic, high));
    CHECK(canopy::compute_stats(automatic).sah_cost == canopy::compute_stats(high).sah_cost);
}

// ---------------------------------------------------------------------------------------------
// Refit

namespace {

// The tree's shape: every wide node's children and counts.
template <typename Prim>
std::vector<std::uint32_t> tree_shape(canopy::bvh<Prim> const& b) {
    std::vector<std::uint32_t> shape;
    for (auto const& w : b.wide_nodes) {
        shape.insert(shape.end(), w.child.begin(), w.child.end());
        shape.insert(shape.end(), w.count.begin(), w.count.end());
    }
    return shape;
}

// The boxes of a refitted tree hold their contents, the root's box is exactly the union of the
// moved triangles', every leaf stores moved[prim_id] with its ids, and a block lane is testable
// exactly when its triangle is not degenerate.
void check_refitted(mesh_bvh const& b, std::vector<triangle> const& moved) {
    walk_result const w = walk(b);
    CHECK(w.structure_ok);
    CHECK(w.bounds_ok);
    canopy::aabb all;
    for (auto const& t : moved) all = extend(all, get_bounds(t));
    CHECK(box_contains(b.bounds(), all));
    CHECK(box_contains(all, b.bounds()));
    CHECK(box_contains(w.root_union, all));
    CHECK(box_contains(all, w.root_union));
    bool stored_ok = true;
    canopy::for_each_primitive(b, [&](triangle const& p) {
        stored_ok = stored_ok && p.prim_id < moved.size() && same_vertices(p, moved[p.prim_id]) &&
                    p.geom_id == moved[p.prim_id].geom_id;
    });
    CHECK(stored_ok);
    bool testable_ok = true;
    for (auto const& block : b.blocks)
        for (int lane = 0; lane < canopy::triangle_block_width; ++lane)
            if (block.prim_id[std::size_t(lane)] != canopy::invalid_id)
                testable_ok = testable_ok && ((block.testable >> lane) & 1u) == (is_degenerate(block.triangle_at(lane)) ? 0u : 1u);
    CHECK(testable_ok);
}

} // namespace

TEST_CASE("refit keeps the tree and rebounds the moved triangles in the wide nodes and the root box") {
    random_source rng(91);
    std::vector<std::pair<char const*, std::vector<triangle>>> const meshes{
        {"soup", test_support::triangle_soup(rng, 2000, 4.0f, 0.5f)}, {"slivers", test_support::sliver_mesh()}};
    for (auto const& [name, mesh] : meshes) {
        for (auto const quality : {canopy::build_quality::fast, canopy::build_quality::high}) {
            for (auto const how : {test_support::deformation::displace, test_support::deformation::twist,
                                   test_support::deformation::collapse}) {
                INFO(name << ", deformation " << int(how) << ", quality " << int(quality));
                auto moved = test_support::deformed(mesh, how, 1.0f, rng);
                // A few triangles made degenerate, and one degenerate triangle made whole again.
                for (std::size_t i = 0; i < moved.size(); i += 97) moved[i].v2 = moved[i].v1;
                mesh_bvh b = canopy::build_binned_sah(mesh, {.quality = quality});
                auto const shape = tree_shape(b);
                canopy::refit(b, moved);
                CHECK(tree_shape(b) == shape);
                check_refitted(b, moved);
                canopy::refit(b, mesh);
                CHECK(tree_shape(b) == shape);
                check_refitted(b, mesh);
            }
        }
    }
}

TEST_CASE("refit of unmoved geometry gives back a fast build's boxes bit for bit, and a high build's or larger") {
    random_source rng(92);
    auto const mesh = test_support::sliver_mesh();
    mesh_bvh const built = canopy::build_binned_sah(mesh, {.quality = canopy::build_quality::fast});
    mesh_bvh b = built;
    canopy::refit(b, mesh);
    REQUIRE(b.wide_nodes.size() == built.wide_nodes.size());
    auto const root = b.bounds(), built_root = built.bounds();
    bool same = std::memcmp(&root, &built_root, sizeof root) == 0;
    for (std::size_t i = 0; i < b.wide_nodes.size(); ++i)
        same = same && std::memcmp(&b.wide_nodes[i], &built.wide_nodes[i], sizeof(b.wide_nodes[i])) == 0;
    CHECK(same);
    CHECK(canopy::sah_drift(b, canopy::compute_stats(built).sah_cost) == 1.0);

    // At high, a leaf held a clipped piece of a long triangle: after a refit, the whole triangle.
    mesh_bvh const high = canopy::build_binned_sah(mesh, {.quality = canopy::build_quality::high});
    mesh_bvh h = high;
    canopy::refit(h, mesh);
    bool contains = true, some_larger = false;
    for (std::size_t i = 0; i < h.wide_nodes.size(); ++i) {
        for (int k = 0; k < canopy::bvh_width; ++k) {
            if (!h.wide_nodes[i].used(k)) continue;
            auto const now = h.wide_nodes[i].child_bounds(k), then = high.wide_nodes[i].child_bounds(k);
            contains = contains && box_contains(now, then);
            some_larger = some_larger || !box_contains(then, now);
        }
    }
    CHECK(contains);
    CHECK(some_larger);
    check_refitted(h, mesh);
}

TEST_CASE("refit refuses a mesh of another size, and refits an empty BVH and a BVH of instances") {
    random_source rng(93);
    auto const mesh = test_support::triangle_soup(rng, 100, 2.0f, 0.5f);
    mesh_bvh b = canopy::build_binned_sah(mesh);
    std::vector<triangle> const fewer(mesh.begin(), mesh.end() - 1);
    CHECK(test_support::what_of<std::invalid_argument>([&] { canopy::refit(b, fewer); }) ==
          "canopy::refit: 99 primitives given for a BVH of 100");
    mesh_bvh empty;
    canopy::refit(empty, std::vector<triangle>{});
    CHECK(empty.empty());

    // Instances of b, refitted after b moved: the top level bounds the moved instances.
    std::vector<canopy::instance<mesh_bvh>> instances;
    for (std::uint32_t k = 0; k < 5; ++k) instances.emplace_back(b, test_support::random_transform(rng, 5.0f), k);
    auto top = canopy::build_binned_sah(instances);
    canopy::refit(b, test_support::deformed(mesh, test_support::deformation::displace, 3.0f, rng));
    canopy::aabb const stale = top.bounds();
    canopy::refit(top);
    walk_result const w = walk(top);
    CHECK(w.structure_ok);
    CHECK(w.bounds_ok);
    canopy::aabb all;
    for (auto const& inst : instances) all = extend(all, get_bounds(inst));
    CHECK(box_contains(top.bounds(), all));
    CHECK(box_contains(all, top.bounds()));
    CHECK_FALSE(box_contains(stale, all)); // the instances moved out of the top level's old box
}

TEST_CASE("SAH drift after refits: counted against a fresh build, and the rebuild advice") {
    // A grid of 64 × 64 squares in the plane z = 0, each split in two, refitted to large twists
    // about the y axis (the grid becomes a helicoid).
    std::vector<triangle> grid;
    for (int i = 0; i < 64; ++i)
        for (int j = 0; j < 64; ++j) {
            auto const p = [](int x, int y) { return vec3<float>(float(x) / 16.0f - 2.0f, float(y) / 16.0f - 2.0f, 0.0f); };
            grid.push_back({p(i, j), p(i + 1, j), p(i + 1, j + 1), std::uint32_t(grid.size()), 0});
            grid.push_back({p(i, j), p(i + 1, j + 1), p(i, j + 1), std::uint32_t(grid.size()), 0});
        }
    random_source rng(94);
    mesh_bvh b = canopy::build_binned_sah(grid);
    double const built = canopy::compute_stats(b).sah_cost;
    double previous = 1.0;
    for (float const turns : {0.05f, 0.5f, 2.0f}) {
        auto const moved = test_support::deformed(grid, test_support::deformation::twist, turns * 6.2831853f / 4.0f, rng);
        canopy::refit(b, moved);
        double const drift = canopy::sah_drift(b, built);
        double const fresh = canopy::compute_stats(canopy::build_binned_sah(moved)).sah_cost / built;
        INFO(turns << " turns over the height: refitted SAH " << drift << " × the built tree's, fresh build " << fresh);
        CHECK(drift >= previous);
        CHECK(drift > fresh);
        CHECK(canopy::needs_rebuild(b, built) == (drift > canopy::default_rebuild_drift));
        previous = drift;
    }
    CHECK(previous > canopy::default_rebuild_drift); // two turns: rebuild
    // A slight twist: the corners move at most 0.008 out of the plane, an eighth of a square's side, so every box
    // gains a thin side wall but keeps its place in the tree; keep refitting. (The flat grid's boxes
    // have no thickness, so the drift grows fast with the twist: 0.05 rad already gives 1.6–1.8,
    // with the tree differing between ISA levels.)
    mesh_bvh small = canopy::build_binned_sah(grid);
    canopy::refit(small, test_support::deformed(grid, test_support::deformation::twist, 0.002f, rng));
    INFO("slight twist: refitted SAH " << canopy::sah_drift(small, built) << " × the built tree's");
    CHECK(canopy::sah_drift(small, built) > 1.0);
    CHECK_FALSE(canopy::needs_rebuild(small, built));
}

// The spatial bins' planes (canopy.bvh:spatial, place_spatial_planes) and the bin a coordinate
// falls in (plane_bin, one subtraction, one multiply and a clamp) must agree: x is in bin k exactly
// when planes[k] ≤ x < planes[k + 1], found here by searching the planes. Checked on each plane,
// the float below it and random coordinates, for nodes far from the origin, a few ulps wide and
// wide enough to overflow; the planes stay within a few ulps of the equal intervals.
TEST_CASE("spatial binning: a coordinate's bin is the one its planes bound, found without a search") {
    random_source rng(2031);
    int checked = 0, refused = 0;
    for (int iteration = 0; iteration < 4000; ++iteration) {
        int const bins = std::array{2, 3, 8, 16, 64}[std::size_t(iteration % 5)];
        float const magnitude = std::array{1.0f, 1e3f, 1e6f, 3e7f, 1e30f}[std::size_t((iteration / 5) % 5)];
        float lo = rng.uniform(-magnitude, magnitude), hi = 0.0f;
        switch ((iteration / 25) % 4) {
        case 0: hi = lo + rng.uniform(0.0f, 2.0f * magnitude); break;             // a box of the scene's size
        case 1: hi = lo + rng.uniform(0.0f, 1e-3f) * std::abs(lo); break;         // small against its distance
        case 2: hi = std::nextafter(std::nextafter(lo, INFINITY), INFINITY); break; // two ulps wide
        default:                                                                    // wider than a float holds
            lo = -0.75f * std::numeric_limits<float>::max();
            hi = rng.uniform(0.5f, 1.0f) * std::numeric_limits<float>::max();
        }
        if (!(hi > lo)) continue;
        std::vector<float> planes(std::size_t(bins) + 1);
        float const scale = canopy::detail::place_spatial_planes(lo, hi, bins, planes.data());
        if (scale == 0.0f) {
            // Refused only where the planes cannot follow the bins: a width that overflows.
            INFO("bins " << bins << ", [" << lo << ", " << hi << "]");
            CHECK_FALSE(std::isfinite(hi - lo));
            ++refused;
            continue;
        }
        REQUIRE(planes.front() == lo);
        REQUIRE(planes.back() == hi);
        double const ulp = double(std::nextafter(std::max(std::abs(lo), std::abs(hi)), INFINITY)) -
                           double(std::max(std::abs(lo), std::abs(hi)));
        for (int k = 1; k < bins; ++k) {
            double const even = double(lo) + (double(hi) - double(lo)) * k / bins;
            INFO("bins " << bins << ", [" << lo << ", " << hi << "], plane " << k);
            CHECK(planes[std::size_t(k)] >= planes[std::size_t(k) - 1]);
            CHECK(std::abs(double(planes[std::size_t(k)]) - even) <= 4.0 * ulp);
        }
        auto const bin_by_search = [&](float x) {
            int k = 0;
            while (k + 1 < bins && x >= planes[std::size_t(k) + 1]) ++k;
            return k;
        };
        std::vector<float> xs;
        for (float const p : planes) {
            xs.push_back(p);
            xs.push_back(std::nextafter(p, -INFINITY));
            xs.push_back(std::nextafter(p, INFINITY));
        }
        for (int i = 0; i < 8; ++i) xs.push_back(float(rng.uniform_double(double(lo), double(hi))));
        for (float const x : xs) {
            if (x < lo || x > hi) continue;
            INFO("bins " << bins << ", [" << lo << ", " << hi << "], x " << x);
            CHECK(canopy::detail::plane_bin(x, planes.data(), bins, scale) == bin_by_search(x));
            ++checked;
        }
    }
    CHECK(checked > 50000);
    CHECK(refused > 0);
}

// The spatial splits' binning clips a reference that spans several bins into one part per bin
// (canopy.bvh:spatial): the 4-lane sweep, with its own path for two bins, must give the boxes of
// the scalar clipping, bin by bin. Random triangles, needles among them, references clipped to
// random boxes as split references are, and vertices on dyadic grids, so that vertices fall
// exactly on the planes.
TEST_CASE("spatial binning: the vector sweep gives the scalar clipping's part boxes, with two bins or more") {
    if constexpr (!canopy::simd::native_width<4>) {
        SUCCEED("no 4-lane vectors in this build: the builder bins with the scalar clipping only");
    } else {
        using canopy::aabb;
        constexpr int bins = 16;
        random_source rng(2026);
        int two_bins = 0, more_bins = 0;
        for (int iteration = 0; iteration < 40000; ++iteration) {
            bool const on_grid = iteration % 3 == 0;
            auto const point = [&] { return on_grid ? rng.dyadic_point(-2.0f, 2.0f, 3) : rng.point(-2.0f, 2.0f); };
            triangle tri{point(), point(), point(), 0, 0};
            if (iteration % 5 == 1) { // a needle: two vertices close together, the third far away
                tri.v1 = tri.v0 + rng.point(-1e-3f, 1e-3f);
            } else if (iteration % 5 == 2) { // about a bin wide: most span two bins
                tri.v1 = tri.v0 + rng.point(-0.3f, 0.3f);
                tri.v2 = tri.v0 + rng.point(-0.3f, 0.3f);
            }
            aabb const tri_box = canopy::get_bounds(tri);
            aabb ref = tri_box;
            if (iteration % 2 == 0) { // a reference clipped by earlier splits
                aabb const cut{rng.point(-2.0f, 0.5f), rng.point(-0.5f, 2.0f)};
                ref = canopy::intersection(tri_box, cut);
                if (canopy::is_empty(ref)) continue;
            }
            // The node: the grid's box (planes at multiples of 1/4), or the reference's box grown.
            aabb const node = on_grid ? aabb{vec3<float>(-2.0f), vec3<float>(2.0f)}
                                      : aabb{ref.min - rng.point(0.0f, 1.0f), ref.max + rng.point(0.0f, 1.0f)};
            int const axis = rng.integer(0, 2);
            float const lo = node.min[axis], hi = node.max[axis];
            if (!(hi > lo)) continue;
            std::array<float, bins + 1> planes{};
            float const scale = canopy::detail::place_spatial_planes(lo, hi, bins, planes.data());
            int const first = canopy::detail::plane_bin(ref.min[axis], planes.data(), bins, scale);
            int const last = canopy::detail::last_plane_bin(ref.max[axis], first, planes.data(), bins, scale);
            if (first == last) continue;
            (last == first + 1 ? two_bins : more_bins) += 1;

            std::array<aabb, bins> scalar_boxes{}, parts{};
            canopy::detail::bin_reference_parts(tri, ref, axis, planes.data(), bins, scale, first, last,
                                                scalar_boxes.data(), parts.data());
            std::array<canopy::detail::vector_bin, bins> vector_boxes;
            for (auto& b : vector_boxes) b = {canopy::simd::float4(inf), canopy::simd::float4(-inf)};
            canopy::detail::vector_bin const ref_lanes{canopy::to_lanes(ref.min), canopy::to_lanes(ref.max)};
            canopy::detail::bin_reference_parts_vector(tri, ref_lanes, axis, planes.data(), bins, scale, first, last,
                                                       vector_boxes.data());
            for (int k = 0; k < bins; ++k) {
                auto const& s = scalar_boxes[std::size_t(k)];
                auto const vmin = canopy::from_lanes(vector_boxes[std::size_t(k)].lo);
                auto const vmax = canopy::from_lanes(vector_boxes[std::size_t(k)].hi);
                for (int c = 0; c < 3; ++c) {
                    if (s.min[c] == vmin[c] && s.max[c] == vmax[c]) continue;
                    INFO("iteration " << iteration << ", axis " << axis << ", bins " << first << ".." << last
                                      << ", bin " << k << ", component " << c);
                    CHECK(s.min[c] == vmin[c]);
                    CHECK(s.max[c] == vmax[c]);
                }
            }
        }
        // Both paths of the sweep ran, many times.
        CHECK(two_bins > 1000);
        CHECK(more_bins > 10000);
    }
}
