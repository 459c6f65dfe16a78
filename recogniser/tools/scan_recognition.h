// Scan and recognise (issue 5, `sope scan-and-recognise`): a frame set is decoded and
// triangulated (calibration/scan.h), the cloud is cut down to the object, and the
// recogniser names it and estimates its pose — one function shared by the command line,
// the full-loop test and the latency bench. Also the virtual scenes the command scans
// without hardware (a procedural household object in a seeded pose before a backdrop) and
// the overlay picture of a result.
//
// Segmentation. A scan sees the object and whatever is around it (a backdrop, a wall). The
// object is isolated with the pre-processing's range band (recogniser/preprocess.h, thesis
// §4.2: "conditional / pass-through filter, also the segmentation"): only points whose
// distance from the camera ‖p‖ lies in [min_range, max_range] are kept. The virtual scenes
// put the backdrop beyond the object's farthest point with a margin and give the band that
// separates them (RecognitionScene::segmentation); on a real rig the user sets the band.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "calibration/scan.h"
#include "core/camera_model.h"
#include "core/frame_set.h"
#include "core/mesh.h"
#include "core/point_cloud.h"
#include "core/rig_calibration.h"
#include "core/rigid3d.h"
#include "recogniser/recogniser.h"
#include "simulator/procedural_objects.h"
#include "simulator/virtual_rig.h"

namespace sope {

struct ObjectSegmentationOptions {
  // Range band, metres from the camera centre (‖p‖).
  double min_range = 0.05;
  double max_range = 2.0;
  void Check() const;
};

// The finite points of `cloud` (with their colours) whose range lies in the band.
PointCloud SegmentByRange(const PointCloud& cloud, const ObjectSegmentationOptions& options);

// Milliseconds (wall clock) from the last captured frame to the recognition result.
struct ScanRecognitionTimings {
  double decode = 0.0;
  double triangulate = 0.0;
  double segment = 0.0;
  double recognise = 0.0;  // Recogniser::Recognise, all stages
  double total = 0.0;      // the four together (measured around them)
};

// How a scan ended. A scan with nothing to recognise is a result, not an error: the object
// may have been lifted away between two scans of a continuous run.
enum class ScanStatus {
  kRecognised,     // the recogniser gave at least one suggestion
  kNoSuggestion,   // the recogniser ran and found no comparable view
  kNoPoints,       // nothing triangulated (no projector light, or a wrong calibration)
  kNothingInBand,  // fewer than kMinObjectPoints points in the range band
};
// "recognised", "no suggestion", "no points", "nothing in band".
std::string ToString(ScanStatus status);
// The object cloud needs this many points to be worth recognising.
constexpr size_t kMinObjectPoints = 50;

struct ScanRecognition {
  ScanStatus status = ScanStatus::kRecognised;
  std::string message;     // what happened, when the status is not kRecognised
  ScanResult scan;         // correspondences and the full cloud
  PointCloud object;       // the segmented cloud given to the recogniser
  RecognitionResult recognition;  // empty unless the recogniser ran
  ScanRecognitionTimings timing;
};

// Decode + triangulate `frames` with `triangulator` (built once per calibration: it holds
// the undistortion tables, ~0.2 s for a 1280×720 camera, not part of a scan's latency),
// segment, recognise. When nothing is triangulated or nothing is left in the band the
// recogniser is not run and the status says so (the message gives the point counts and the
// band). Throws sope::Error on invalid options or when the recogniser refuses the cloud.
ScanRecognition RecogniseFrameSet(const FrameSet& frames, const Triangulator& triangulator,
                                  const DecoderOptions& decoder_options,
                                  const ObjectSegmentationOptions& segmentation,
                                  const Recogniser& recogniser,
                                  const RecognitionOptions& recognition_options);
// The same after decoding and triangulating (ScanFrameSet, or ScanDecoded for a map the
// live loop decoded during the capture): segment and recognise; the timings include the
// scan's decode_ms and triangulate_ms.
ScanRecognition RecogniseScan(ScanResult scan, const ObjectSegmentationOptions& segmentation,
                              const Recogniser& recogniser,
                              const RecognitionOptions& recognition_options);
// The same, building the triangulator from `calibration` (its time not counted).
ScanRecognition RecogniseFrameSet(const FrameSet& frames, const RigCalibration& calibration,
                                  const ScanOptions& scan_options,
                                  const ObjectSegmentationOptions& segmentation,
                                  const Recogniser& recogniser,
                                  const RecognitionOptions& recognition_options);

// ---------------------------------------------------------------------------------------
// Tabletop scans.

// Code consistency (decoder/code_consistency.h) is most of a table scene's decode, and
// most of the pixels it fills lie on the table plane, which the segmentation then drops
// (a 4-object scene: 68k of 86k). A tabletop scan therefore fills only near what stands on
// the table: the frames are decoded without code consistency and sub-pixel edges
// (`plain`, decoded with PlainTableDecoderOptions: given — the live loop decodes it during
// the capture, `plain_decode_ms` its time after the last frame — or decoded here) and
// triangulated, the table plane is found in those points (FindTablePlane with
// `segmentation`'s range band and plane options), and the consistency fills only pixels
// within its reach (passes × window radius) of a point standing on the table
// (min_height–max_height above it, in the range band; everywhere when there is no plane),
// growing from those points (their pixels its seeds, FillFromConsistentNeighbours): the
// fills of what stands on the table are those of the whole image but for any reached only
// across the table, and the table around the objects is left as decoded (procedural
// tables: 19k fills of a scene instead of 30k; ~10 ms less after the last frame). Then
// the sub-pixel edges, when on, and the triangulation of the whole map. Phase sets and
// options without consistency: the usual scan (ScanFrameSet / ScanDecoded). decode_ms
// counts the decoding, the plane and the region; triangulate_ms both triangulations.
struct TableSegmentationOptions;
DecoderOptions PlainTableDecoderOptions(const DecoderOptions& options);
ScanResult ScanTableFrameSet(const FrameSet& frames, const Triangulator& triangulator,
                             const DecoderOptions& options,
                             const TableSegmentationOptions& segmentation,
                             CorrespondenceMap* plain = nullptr, double plain_decode_ms = 0.0);

// ---------------------------------------------------------------------------------------
// Virtual scenes for recognition.

struct RecognitionSceneOptions {
  // Classes drawn from (uniformly); empty: all ten.
  std::vector<ObjectClass> classes;
  // Instance seed of the object = instance_seed_base + the scene's instance draw in
  // [0, instance_count). A database written by WriteProceduralModels(dir, n, s) holds the
  // instances s … s + n − 1 of every class; a base ≥ s + n gives unseen instances.
  uint64_t instance_seed_base = 1000;
  int instance_count = 1000;
  // Distance from the camera to the object's bounding-box centre, metres: uniform in
  // [min_distance, max_distance], raised when needed so that the bounding sphere (times
  // fit_margin) fits the camera's smaller field of view.
  double min_distance = 0.5;
  double max_distance = 0.62;
  double fit_margin = 1.1;
  // The centre is moved off the optical axis by up to this, metres (each of x and y).
  double max_lateral_offset = 0.03;
  // A matte backdrop facing the camera, `backdrop_gap` metres beyond the object's farthest
  // possible point (range of the centre + bounding radius); false: none.
  bool backdrop = true;
  double backdrop_gap = 0.15;
  void Check() const;
};

struct RecognitionScene {
  Scene scene;  // the object (objects[0]) and the backdrop (objects[1], if any)
  ObjectClass object_class = ObjectClass::kMug;
  uint64_t instance_seed = 0;
  TriangleMesh mesh;        // model frame, metres (MakeObject(object_class, instance_seed))
  Rigid3d cam_from_model;   // ground truth
  double backdrop_distance = 0.0;  // metres along the optical axis, 0 = none
  // A range band that keeps the whole object and none of the backdrop: [0.05, farthest
  // object point + half the gap].
  ObjectSegmentationOptions segmentation;
  // "mug (instance 1234)".
  std::string Description() const;
};

// Scene `seed` (deterministic): a procedural object of a random class and instance, turned
// by a rotation drawn uniformly from SO(3), its bounding-box centre at a random distance
// near the optical axis, and the backdrop. `camera` sets the field of view to fit.
RecognitionScene MakeRecognitionScene(uint64_t seed, const CameraModel& camera,
                                      const RecognitionSceneOptions& options = {});

// ---------------------------------------------------------------------------------------
// Overlay.

// The grey camera image (CV_8UC1 or CV_16UC1; CV_8UC3 is used as is) in colour with the
// model `mesh` (model frame, metres) at `cam_from_model` projected through `camera`: its
// faces tinted, its outline drawn, and `label` written top left. Faces behind the camera
// are skipped. Returns CV_8UC3 (BGR), the image's size.
cv::Mat DrawRecognitionOverlay(const cv::Mat& image, const CameraModel& camera,
                               const TriangleMesh& mesh, const Rigid3d& cam_from_model,
                               const std::string& label);
// The same with model points only (e.g. a database view cloud when the mesh is not at hand).
cv::Mat DrawRecognitionOverlay(const cv::Mat& image, const CameraModel& camera,
                               const std::vector<Eigen::Vector3f>& points_in_model,
                               const Rigid3d& cam_from_model, const std::string& label);

}  // namespace sope
