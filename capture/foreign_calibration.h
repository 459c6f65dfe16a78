// Other tools' camera–projector calibrations read into ours (RigCalibration, metres):
// procam-calibration's calibrate.py (kamino410/procam-calibration: cv2.stereoCalibrate of
// camera then projector, written with cv2.FileStorage) and SLStudio's calibration.xml
// (jakobwilm/slstudio src/calibrator/CalibrationData.cpp).
#pragma once

#include <string>

#include "core/rig_calibration.h"

namespace sope {

enum class ForeignCalibrationFormat {
  // procam-calibration's calibration_result.xml (any cv::FileStorage format): img_shape
  // (camera rows, cols), rms, cam_int, cam_dist, proj_int, proj_dist, roration (sic; also
  // read as "rotation"), translation. R, T are stereoCalibrate's: X_proj = R·X_cam + T, in
  // the unit of the board's square size. The file has no projector size.
  kProcam,
  // SLStudio's calibration.xml: Kc, kc, Kp, kp, Rp, Tp, cam_error, proj_error,
  // stereo_error, frameWidth, frameHeight, screenResX, screenResY. Its triangulator uses
  // Pp = Kp·[Rp | Tp] on camera-frame points, so X_proj = Rp·X_cam + Tp.
  kSlStudio,
};
std::string ToString(ForeignCalibrationFormat format);
// "procam", "slstudio". Throws sope::Error naming the unknown value.
ForeignCalibrationFormat ForeignCalibrationFormatFromString(const std::string& text);

// Length unit of a foreign file's translation (the board's unit when it was calibrated).
enum class LengthUnit { kMillimetre, kCentimetre, kMetre };
std::string ToString(LengthUnit unit);
// "mm", "cm", "m".
LengthUnit LengthUnitFromString(const std::string& text);
// Metres per unit.
double MetresPer(LengthUnit unit);

// Reads `path` in `format` with translations in `unit`. The projector size comes from the
// file when it has one (SLStudio), else from projector_width/height (procam-calibration),
// which must then be > 0; when both are given they must agree. Throws sope::Error naming
// the file and the missing or malformed key.
RigCalibration ReadForeignCalibration(const std::string& path, ForeignCalibrationFormat format,
                                      LengthUnit unit, int projector_width = 0,
                                      int projector_height = 0);

}  // namespace sope
