// Sources of scans (DESIGN.md data flow, pipeline/): where a scan's frame set comes from —
// recorded frame-set directories, the live rig (a V4L2 camera + projector window, a
// replayed recording, or the virtual rig's built-in scene, through a RigSession), or
// virtual recognition scenes (a procedural object in a seeded pose before a backdrop) with
// their ground truth. The scan-and-recognise controller (pipeline/scan_and_recognise.h),
// `sope scan` and the tests take any of them.
#pragma once

#include <atomic>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "capture/rig_session.h"
#include "core/frame_set.h"
#include "core/mesh.h"
#include "core/rig_calibration.h"
#include "core/rigid3d.h"
#include "pipeline/live_rig.h"
#include "projector/patterns.h"
#include "recogniser/database.h"
#include "recogniser/tools/scan_recognition.h"
#include "simulator/procedural_objects.h"
#include "simulator/table_scene.h"
#include "simulator/virtual_rig.h"

namespace sope {

// One object of a virtual scene.
struct ScanObjectTruth {
  std::string model, class_name;  // names a database built from the same meshes gives
  uint64_t instance_seed = 0;     // procedural objects
  bool known = true;              // false: clutter, in no database
  TriangleMesh mesh;              // model frame, metres
  Rigid3d cam_from_model;
  double visible_fraction = 1.0;  // pixels seen in the scene / pixels when alone
  int gt_object_id = 0;           // the simulator's object index + 1
};

// What the scene really held (virtual sources only). The single fields describe the
// scene's one object — on a table, its most visible known object; `objects` lists every
// object (for single-object scenes: that object).
struct ScanTruth {
  std::string class_name;
  uint64_t instance_seed = 0;
  TriangleMesh mesh;       // model frame, metres
  Rigid3d cam_from_model;
  std::vector<ScanObjectTruth> objects;  // known first, then clutter
  // Tabletop scenes: the table plane in the camera frame, n·x + d = 0, unit n towards
  // the camera.
  std::optional<Eigen::Vector4d> table_plane_in_cam;
};

struct SourceScan {
  FrameSet frames;
  RigCalibration calibration;  // the rig the frames were taken with
  std::string calibration_source = "the calibration";  // names it in messages
  std::string source;          // "virtual", "/dev/video0", the frame-set directory, …
  std::optional<ScanTruth> truth;
  // The scene is a tabletop (several objects on a dominant plane): the controller
  // segments by the table, not by a range band alone.
  bool tabletop = false;
  // A range band that keeps the object and none of the background, when the source knows
  // one (the single-object virtual scenes do; table scenes give none: the tabletop path
  // segments by the table); else the controller's default.
  std::optional<ObjectSegmentationOptions> band;
  double capture_ms = 0.0;     // capturing or loading the frame set
};

// (frames done, frames in the sequence) while a scan is captured.
using CaptureProgress = std::function<void(size_t done, size_t total)>;

class ScanSource {
 public:
  virtual ~ScanSource() = default;
  // How many scans the source holds; −1: as many as asked for (a live rig).
  virtual int size() const = 0;
  // True when every scan is taken with the same calibration (a triangulator is reused).
  virtual bool fixed_calibration() const = 0;
  // Scan `index` (0, 1, … in order). Throws sope::Error on failure (an unreadable frame
  // set, a lost camera, cancellation).
  virtual SourceScan Next(int index, const CaptureProgress& progress = {}) = 0;
  // Frames as they are captured (RigSession::SetFrameSink), for decoding during the
  // capture; sources that do not capture (recorded frame sets) ignore it.
  virtual void SetFrameSink(RigSession::FrameSink sink) {}
};

// Recorded frame sets, one scan each, in the order given. `calibration_path` (empty: the
// file each frames.json names) is the rig.
class FrameSetDirectorySource : public ScanSource {
 public:
  FrameSetDirectorySource(std::vector<std::string> directories, std::string calibration_path);
  int size() const override { return static_cast<int>(directories_.size()); }
  bool fixed_calibration() const override { return false; }
  SourceScan Next(int index, const CaptureProgress& progress = {}) override;

 private:
  std::vector<std::string> directories_;
  std::string calibration_path_;
};

// The live rig: OpenLiveRig(spec) driven by a RigSession, the pattern sequence of
// `patterns` per scan. "virtual" is the built-in scene (MakeDemoScene, the mug of seed 0)
// with its ground truth and a band that ends 0.1 m beyond the mug's centre (the backdrop
// is 0.15 m behind it). With `record_directory`, Next(0) also records the frame set there
// (calibration.yaml, capture.json; RigSession::Record) — one scan only.
struct LiveRigSourceOptions {
  std::string spec;                 // "/dev/videoN", "virtual", "replay:DIR"
  RigCalibration calibration;
  std::string calibration_source = "the calibration";
  PatternOptions patterns;          // projector size = the calibration's
  LiveRigOptions rig;
  RigSessionOptions session;        // its `cancel` stops a capture
  std::string record_directory;
  void Check() const;
};
class LiveRigSource : public ScanSource {
 public:
  explicit LiveRigSource(const LiveRigSourceOptions& options);
  int size() const override { return options_.record_directory.empty() ? -1 : 1; }
  bool fixed_calibration() const override { return true; }
  SourceScan Next(int index, const CaptureProgress& progress = {}) override;
  void SetFrameSink(RigSession::FrameSink sink) override { session_->SetFrameSink(std::move(sink)); }

 private:
  LiveRigSourceOptions options_;
  LiveRig rig_;
  std::unique_ptr<RigSession> session_;
  std::vector<Pattern> sequence_;
};

// Virtual recognition scenes on the virtual rig (the true calibration), captured through
// a RigSession like a live scan: scan i shows MakeRecognitionScene(seed + i) — a new
// object in a new pose — with its ground truth and its band.
struct VirtualSceneSourceOptions {
  RigCalibration calibration;       // default: the virtual rig's true calibration
  RecognitionSceneOptions scenes;
  uint64_t seed = 1;
  PatternOptions patterns;          // projector size = the calibration's
  LiveRigOptions rig;               // the virtual camera's delay and jitter
  RigSessionOptions session;
  void Check() const;
};
class VirtualSceneSource : public ScanSource {
 public:
  explicit VirtualSceneSource(const VirtualSceneSourceOptions& options);
  int size() const override { return -1; }
  bool fixed_calibration() const override { return true; }
  SourceScan Next(int index, const CaptureProgress& progress = {}) override;
  void SetFrameSink(RigSession::FrameSink sink) override { session_->SetFrameSink(std::move(sink)); }
  // The scene of the last Next (before the first: of scan 0).
  const RecognitionScene& scene() const { return scene_; }

 private:
  VirtualSceneSourceOptions options_;
  RecognitionScene scene_;
  LiveRig rig_;
  std::unique_ptr<RigSession> session_;
  std::vector<Pattern> sequence_;
};

// Tabletop scenes on the virtual rig (simulator/table_scene.h), captured through a
// RigSession: scan i shows MakeTableScene with seed + i — the meshes of `table.objects`
// when given (the same objects, re-placed every scan), else `objects` procedural objects
// (0: 3–5, drawn per scene) of `classes` with instance seeds instance_seed_base + [0,
// instance_count) (unseen instances by default) — under `sensor` (TableSensorOptions: hard
// and realistic). Every object's truth (visible fraction included) is in SourceScan::truth;
// the scan is flagged `tabletop`.
struct VirtualTableSourceOptions {
  RigCalibration calibration;       // default: the virtual rig's true calibration
  TableSceneOptions table;          // objects (optional), clutter, backdrop, tilt, distance
  int objects = 0;                  // procedural objects per scene, 0 = 3–5
  std::vector<ObjectClass> classes; // empty: all ten
  uint64_t instance_seed_base = 1000;
  int instance_count = 1000;
  uint64_t seed = 1;
  SensorOptions sensor = TableSensorOptions();
  PatternOptions patterns;          // projector size = the calibration's
  LiveRigOptions rig;               // the virtual camera's delay and jitter
  RigSessionOptions session;
  void Check() const;
};
class VirtualTableSource : public ScanSource {
 public:
  explicit VirtualTableSource(const VirtualTableSourceOptions& options);
  int size() const override { return -1; }
  bool fixed_calibration() const override { return true; }
  SourceScan Next(int index, const CaptureProgress& progress = {}) override;
  void SetFrameSink(RigSession::FrameSink sink) override { session_->SetFrameSink(std::move(sink)); }
  // The scene of the last Next (before the first: of scan 0).
  const TableScene& scene() const { return scene_; }
  // The options MakeTableScene gets for scan `index`: draw 0, 1, … of the procedural
  // objects (a draw that does not fit on the table is replaced by the next, at most
  // kProceduralDraws).
  TableSceneOptions SceneOptions(int index, int draw = 0) const;
  static constexpr int kProceduralDraws = 20;

 private:
  TableScene MakeScene(int index) const;
  VirtualTableSourceOptions options_;
  TableScene scene_;
  LiveRig rig_;
  std::unique_ptr<RigSession> session_;
  std::vector<Pattern> sequence_;
};
// The ground truth of a table scene (its visible fractions computed).
ScanTruth TableSceneTruth(const TableScene& scene);

// The database's classes that are procedural classes (mug, bottle, …: what virtual scenes
// can show), in the database's order.
std::vector<ObjectClass> ProceduralClassesIn(const Database& database);
// Names a table object drawn from one of the database's mesh files (the same file as a
// model's source_path) as the database names that model: its name and class. A database
// built from DIR/<group>/<model>.obj gives the model the class <group>, which the file's
// name alone does not tell (TableObjectNames would make its class the stem). Objects
// already named, and files of no model, keep their names.
void NameAsInDatabase(const Database& database, TableObjectSpec* spec);
// Restricts the scenes to `spec`: "CLASS" (any instance) or "CLASS:SEED" (that instance).
// Throws sope::Error naming the spec for an unknown class or a malformed seed.
void RestrictScenesToObject(const std::string& spec, RecognitionSceneOptions* scenes);

}  // namespace sope
