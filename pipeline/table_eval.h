// Tabletop evaluation (issue 12, `sope eval --table`): table scenes of several objects
// (simulator/table_scene.h) scanned through the full pipeline on the virtual rig (patterns
// rendered, captured by a RigSession, decoded, triangulated) and recognised by the
// scan-and-recognise controller in tabletop mode; every recognised object matched with the
// ground truth (MatchTableObjects). Figures:
//  - detection recall: known objects detected right (model right, ADD-S < adds_fraction of
//    the diameter) / known objects; precision: right detections / all detections;
//  - class recall: known objects whose matched detection has the right class / known
//    objects (the figure for unseen procedural instances);
//  - pose errors of the class-correct matches: rotation modulo symmetry, centre;
//  - unknown-object rejection: clutter objects no detection was matched to / clutter;
//  - per-stage milliseconds (decode, triangulate, segment, recognise, frame to result).
#pragma once

#include <functional>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "pipeline/scan_and_recognise.h"
#include "pipeline/scan_source.h"
#include "recogniser/database.h"

namespace sope {

struct TableEvalOptions {
  // Mesh specs (files or builtin:CLASS[:SEED]) in the database: each scene shows
  // min_objects–max_objects of them drawn at random, each scaled as build-db scaled it
  // (by the database's mesh unit, build-db --units; without one, kept when its size is
  // plausible in metres, else to a 0.25 m diagonal): the database's model, whatever the
  // file's units. Empty: procedural objects of the
  // database's procedural classes, unseen instances (VirtualTableSource's default).
  std::vector<std::string> meshes;
  int scenes = 10;
  int min_objects = 3;
  int max_objects = 5;
  int clutter = 1;  // unknown clutter objects per scene
  uint64_t seed = 1;
  double adds_fraction = 0.1;
  ScanAndRecogniseOptions controller;  // tabletop is forced on; out_dir: per-scan files
  // Calibration (an empty one: DefaultRigCalibration), tilt, distance, sensor, …; the
  // pattern projector size follows the calibration.
  VirtualTableSourceOptions source;
  void Check() const;
};

struct TableEvalSummary {
  int scenes = 0;
  int skipped_scenes = 0;  // procedural scenes whose objects could not all be placed
  int known = 0, detections = 0, correct = 0, class_correct = 0;
  int clutter = 0, clutter_rejected = 0;
  // Known objects ≥ 50% visible, those detected right, those of the right class.
  int visible_known = 0, visible_correct = 0, visible_class_correct = 0;
  double recall = 0, precision = 0, class_recall = 0, rejection = 0, visible_recall = 0,
         visible_class_recall = 0;
  // Per true class of the known objects: objects, those detected right, those of the right
  // class.
  struct ClassCounts {
    int known = 0, correct = 0, class_correct = 0;
  };
  std::map<std::string, ClassCounts> per_class;
  // (true class, detected class) → objects: "clutter" the unknown objects' class, a detected
  // class "none" an object nothing was matched to, a true class "none" a detection matched
  // to no object.
  std::map<std::pair<std::string, std::string>, int> confusion;
  std::vector<double> rotation_errors_deg, center_errors_m;  // class-correct matches
  double median_rotation_deg = 0, median_center_m = 0;
  // Per stage: median and 95th percentile, ms.
  std::vector<std::string> stage_names;
  std::vector<double> stage_median_ms, stage_p95_ms;
  std::vector<std::string> scan_lines;  // every scan's JSON line
  std::string patterns;                 // the scanned pattern sequence (DescribePatterns)
  // Markdown report.
  std::string Markdown() const;
  std::string Json() const;
};

// Runs the scenes; with `out_dir` writes report.md, report.json, confusion.png (rows the
// true classes, columns the detected ones), rotation_errors.png, center_errors.png and
// (when options.controller.out_dir is empty) the per-scan files under out_dir/scans.
// `progress(done, total)` after each scene.
TableEvalSummary RunTableEvaluation(const Database& database, const TableEvalOptions& options,
                                    const std::string& out_dir,
                                    const std::function<void(int, int)>& progress = {});

}  // namespace sope
