// Reports of a rig calibration beside its YAML: per-view figures as JSON and a picture of
// the residuals (`sope calibrate` writes CAL.report.json and CAL.residuals.png).
#pragma once

#include <string>

#include <opencv2/core/mat.hpp>

#include "calibration/rig_calibrator.h"

namespace sope {

// JSON ("format": "sope-calibration-report/1"): the board, RMS per device, solver figures,
// and per view its name, status (used / dropped and why / board not found), corner counts,
// RMS per device (pixels) and cam_from_board (rotation 3×3, translation metres).
std::string CalibrationReportJson(const CalibrationSummary& summary);
// Writes CalibrationReportJson atomically. Throws sope::Error on I/O failure.
void WriteCalibrationReport(const std::string& path, const CalibrationSummary& summary);

// A BGR picture: per-view RMS bars for camera and projector (dropped views marked, views
// without the board left empty, the median as a line) above two scatter plots of every
// corner's residual vector (predicted − observed, pixels) in the camera and the projector,
// coloured by view, with rings at 0.1, 0.5 and 1 px (or scaled to the largest residual).
cv::Mat DrawResidualPlot(const CalibrationSummary& summary);

// "DIR/cal.yaml" → "DIR/cal" + suffix (e.g. ".report.json"); names without an extension
// get the suffix appended.
std::string CalibrationSidecarPath(const std::string& calibration_path, const std::string& suffix);

}  // namespace sope
