// Umbrella module: `import canopy;` brings in every library module.
export module canopy;
export import canopy.simd;
export import canopy.math;
