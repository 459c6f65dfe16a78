// Angle units in one place: the code works in radians (STYLE.md §3); degrees appear only at
// the CLI and in reports, converted with these.
#pragma once

namespace sope {

inline constexpr double kPi = 3.14159265358979323846;
inline constexpr double kRadToDeg = 180.0 / kPi;
inline constexpr double kDegToRad = kPi / 180.0;

constexpr double RadToDeg(double radians) { return radians * kRadToDeg; }
constexpr double DegToRad(double degrees) { return degrees * kDegToRad; }

}  // namespace sope
