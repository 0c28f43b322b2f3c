// canopy.testing — the helpers the tests share, one module built with the tests only (target
// canopy_testing): `import canopy.testing;` after the test file's includes, in any order with its
// other imports. Catch2's macros stay in <catch2/catch.hpp>, which each test file includes.
//
//   :files   (namespace test_support) temp_folder, special files, what_of, run_command
//   :random  (test_support) random_source, triangle and needle soups, sliver_mesh, random_rays,
//            deformed, random_transform, pack (eight rays as a packet), checkerboard_opaque
//   :nested  (test_support) nested_scene (three instance levels), instanced_brute_force_hits
//   :stress  (namespace stress_support) the stress battery's sizes, quality, transforms, bitwise
//            comparison and descriptions of hits, failure_log
// The scene and plugin tests' helpers are the module canopy.testing.scene (target
// canopy_testing_scene): hit_double, limits_guard, error_of, message_of, load_failure.
export module canopy.testing;
export import :files;
export import :random;
export import :nested;
export import :stress;
