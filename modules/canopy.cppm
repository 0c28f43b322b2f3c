// Umbrella module: `import canopy;` brings in every library module.
export module canopy;
export import canopy.simd;
export import canopy.math;
export import canopy.geometry;
export import canopy.intersector;
export import canopy.bvh;
export import canopy.query;
export import canopy.texture;
export import canopy.render;
