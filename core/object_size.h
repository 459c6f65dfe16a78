// One rule for "is this mesh in metres?": a mesh file has no unit, and the classic test
// models are ~1–13 units across. A bounding-box diagonal, read as metres, within
// [kMinPlausibleDiagonal, kMaxPlausibleDiagonal] is taken as metres; anything else is in
// other units and is scaled to kDefaultObjectDiagonal. `build-db` (SizeNormalisationOptions)
// and `simulate` use the same range, so a simulated scan of a mesh has the size of that
// mesh's database model (with simulate's former 1.5 m bound, beetle, homer, cheburashka
// and rocker-arm — 1.0–1.3 units — were scanned at 1 m but stored at 0.25 m). 0.75 m is
// the largest object a tabletop rig working at 0.4–0.8 m sees whole.
//
// The rule guesses: a mesh in millimetres is scaled to 0.25 m whatever its real size, so a
// database of BOP-style models (millimetres) would not match the real objects a rig scans.
// A mesh unit given by the user (`--units mm`: metres per file unit) replaces the guess.
#pragma once

namespace sope {

inline constexpr double kMinPlausibleDiagonal = 0.02;   // metres
inline constexpr double kMaxPlausibleDiagonal = 0.75;   // metres
inline constexpr double kDefaultObjectDiagonal = 0.25;  // metres

inline bool IsPlausibleDiagonal(double diagonal_m, double min_m = kMinPlausibleDiagonal,
                                double max_m = kMaxPlausibleDiagonal) {
  return diagonal_m >= min_m && diagonal_m <= max_m;
}

// Metres per file unit of a mesh whose bounding-box diagonal is `diagonal` file units:
// `mesh_unit` when it is given (> 0); else (0: the guess) 1 when the diagonal is plausible
// in metres, or the factor that scales it to `target_m`.
inline double MeshScale(double diagonal, double mesh_unit, double min_m = kMinPlausibleDiagonal,
                        double max_m = kMaxPlausibleDiagonal,
                        double target_m = kDefaultObjectDiagonal) {
  if (mesh_unit > 0.0) return mesh_unit;
  return IsPlausibleDiagonal(diagonal, min_m, max_m) ? 1.0 : target_m / diagonal;
}

}  // namespace sope
