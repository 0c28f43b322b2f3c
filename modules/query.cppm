// canopy.query — the visibility queries of the paper: closest_hit, any_hit, multi_hit<N>, for one
// ray or packet (canopy.query:single) and for a span of rays, traced as packets where they are
// coherent (canopy.query:batch).
export module canopy.query;
export import canopy.bvh;
export import :single;
export import :batch;
