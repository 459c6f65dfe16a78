// Camera–projector rig calibration and its YAML file (DESIGN.md "Calibration").
#pragma once

#include <string>

#include "core/camera_model.h"
#include "core/projector_response.h"
#include "core/rigid3d.h"

namespace sope {

struct RigCalibration {
  CameraModel camera;
  CameraModel projector;
  // X_proj = proj_from_cam.rotation · X_cam + proj_from_cam.translation (metres).
  Rigid3d proj_from_cam;
  // Reprojection RMS of the calibration that produced this file, pixels (0 when unknown,
  // e.g. a simulated rig's true calibration).
  double rms_camera_px = 0.0;
  double rms_projector_px = 0.0;
  double rms_stereo_px = 0.0;
  // Optional (key `projector_response`, a 1×K row): the measured projector → camera
  // intensity response (sope calibrate-gamma); identity when absent.
  ProjectorResponse projector_response;

  // Throws sope::Error when a device model is invalid or the rotation is not a rotation.
  void Check() const;
  // Distance between the camera and projector centres, metres.
  double BaselineLength() const;
};

// Reads the OpenCV FileStorage YAML of DESIGN.md. Throws sope::Error naming the file and
// the missing/malformed key.
RigCalibration ReadRigCalibration(const std::string& path);
// Writes atomically (temporary file + rename). Throws sope::Error on I/O failure.
void WriteRigCalibration(const std::string& path, const RigCalibration& calibration);

}  // namespace sope
