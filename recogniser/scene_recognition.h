// Recognition of every object on a table (issue 12): segment the scan into the table plane
// and the clusters above it (recogniser/segmentation.h), recognise each cluster with the
// single-object pipeline (recogniser/recogniser.h, several posed hypotheses per cluster),
// put each hypothesis down on the table (the plane as a prior: the model's lowest point
// onto the plane when it is within max_snap of it), and verify all hypotheses of the scene
// together (recogniser/scene_verification.h). A cluster whose points an accepted
// hypothesis leaves largely unexplained (two touching objects clustered together) is
// recognised again on its unexplained remainder, once. Clusters nothing explains are
// reported as unknown objects, not as their nearest model.
#pragma once

#include <atomic>
#include <memory>
#include <string>
#include <vector>

#include "core/point_cloud.h"
#include "recogniser/convex_segmentation.h"
#include "recogniser/database.h"
#include "recogniser/near_symmetry.h"
#include "recogniser/recogniser.h"
#include "recogniser/scene_verification.h"
#include "recogniser/segmentation.h"

namespace sope {

struct SceneRecognitionOptions {
  TableSegmentationOptions segmentation;
  RecognitionOptions recognition;  // per cluster
  // Per cluster, the widened pose search runs its batches while none verifies, whatever
  // the best score so far (recognition.widening.continue_below is not applied): a
  // cluster's score is lowered by its segmentation (a part of an object, two objects
  // merged) and by unseen instances, so a 0.7 answer is not the confirmed one it is for a
  // whole object of the database (procedural tables, six seeds: 237 rather than 239 of 287
  // objects of the right class with continue_below applied). Each batch then also screens
  // all its views (recognition.widening.screen_stop is not applied either: on the six seeds
  // it lost a saucepan the full batch found, 242 rather than 243).
  bool widen_every_batch = true;
  SceneVerificationOptions verification;
  // Posed suggestions of each cluster that become scene hypotheses, and the least
  // recognition (alignment) score they need.
  int hypotheses_per_cluster = 3;
  double min_hypothesis_score = 0.15;
  // The plane prior: shift each hypothesis along the table normal so that its lowest model
  // point rests on the plane, when it is within max_snap metres of it (false: off).
  // Tabletop objects rest on the table; ICP alone can slide a hypothesis along a
  // featureless direction (a bottle whose top is outside the image slid along its axis).
  // A hypothesis whose lowest point is more than max_float metres above or below the plane
  // does not rest on the table and is dropped (with snap_to_plane and a table found). A
  // large snap (an object cut by the image border, slid along its axis) is then judged by
  // the scene verification like any hypothesis.
  bool snap_to_plane = true;
  double max_snap = 0.08;
  double max_float = 0.08;
  // A posed suggestion snapped by at least keep_unsnapped_from metres is also kept where
  // the recogniser put it (0: never), when its class has several database models: an
  // unseen instance of another size than the database's, fitted to the side the camera
  // saw, has its lowest point off the table, and snapping it there moves its fitted side
  // off the scan (a lying can wider than every database can, a glass narrower than the one
  // on the table). (An instance database — one model per class — holds the object itself,
  // of its size: there the snapped pose stands alone.) Such a hypothesis loses
  // float_weight × (its lowest point's height above the table / its diameter) of its
  // explained points in the selection: of two that explain the scene alike, the resting one
  // wins, and a floating model over unknown clutter gains less. Procedural tables, seeds
  // 301–601 (189 objects): 151 → 157 classes right with 0.004 and 1.0 (0.01: 154; weight
  // 0: 155 but 2 clutter objects of 48 accepted; 2: 156, 4: 153).
  double keep_unsnapped_from = 0.004;
  double float_weight = 1.0;
  // Each hypothesis also upside down (half a turn about a horizontal axis, put down on
  // the table), and the stability prior of the verification: a hypothesis's gain loses
  // stability_weight × (height of its centre of mass above the table / its diameter) of
  // its explained points — of two that explain the scene alike, the lower one wins.
  bool flip_hypotheses = true;
  // A posed suggestion that does not rest on the table (lowest point more than max_float
  // off the plane: an unseen instance fitted to the seen side, its unseen side sunk into
  // the table) is replaced by its nearest resting pose: turned the least (at most
  // max_rest_turn_deg) that puts a stable face of its model's hull on the table, then put
  // down on it. 0: such suggestions are dropped.
  double max_rest_turn_deg = 45.0;
  // A posed suggestion snapped onto the table by at least rest_refit_from metres (its
  // recognised pose sank into the table or floated: a lying object fitted to a part of it,
  // turned about its long axis), of a class its recognition gives at least
  // rest_refit_min_class_probability, also gets a refit: turned onto each of the
  // rest_refit_faces resting faces of its model nearest its pose and refined there on the
  // points it was recognised from with the table as a constraint (short ICPs, each followed
  // by putting the pose back onto its nearest resting face); the best-scoring one, when it
  // scores at least rest_refit_min_score on those points, is judged by the scene
  // verification beside it (0: off).
  double rest_refit_from = 0.01;
  int rest_refit_faces = 3;
  double rest_refit_min_class_probability = 0.5;
  double rest_refit_min_score = 0.5;
  double stability_weight = 0.2;
  // The class evidence in the selection: a hypothesis's gain also loses class_weight × (1 −
  // the probability the recogniser gave its class) of its explained points — of two that
  // explain the scene about alike (a mug with its handle found and a glass a little wider),
  // the one of the class the views point to wins (0: geometry alone). 0.4: procedural
  // tables, seeds 301–601, 146 → 148 of 189 classes against 0.1 (a mug lying on its side,
  // its handle hidden, no longer taken for a can or a glass), 0.25 and 0.6 147; held-out
  // seeds 701 and 801 76 of 98 either way; YCB tables unchanged.
  double class_weight = 0.4;
  // A cluster whose accepted hypotheses leave at least other_class_remainder of its points
  // unexplained (0: never) also gets the looks of each other class its recognition posed
  // with a verification within other_class_margin of the first class's: that class's
  // best suggestion and its siblings, each turned about its axis of near symmetry, and the
  // best of those scaled to the cluster; the class evidence of the cluster's hypotheses
  // (class_weight) is then that of their best looks. An unseen mug lying on its side,
  // its handle in view, that a glass fits better than the database's mugs: the glass
  // leaves the handle unexplained (15% of the cluster), a sibling mug turned to put its
  // handle there explains it. Procedural tables, seeds 301–1101: 206 → 207 of 235
  // classes; held-out seeds 1201–1401: the same objects; YCB and classic tables unchanged.
  // The looks start from the class's best posed suggestion, also when the cut to top_k
  // left it out of the suggestions (RecognitionResult::other_class_poses), and the margin
  // is 0.35 (was 0.2): that mug (seed 901, scene 7) was lost again once its class's best
  // pose verified 0.585 against the glass's 0.878, below the cut of four glasses. Seeds
  // 301–2201: 654 → 656 of 769 classes, none lost, clutter rejected 190 of 192 either way.
  double other_class_remainder = 0.05;
  double other_class_margin = 0.35;
  // Of those looks, a suggestion or sibling scoring this much or more below the cluster's
  // accepted hypothesis is not turned (the turns that found the mug started from 0.77–0.87
  // against the glass's 0.89; those dropped on the live loop's scans from 0.32–0.72).
  double other_class_roll_within = 0.12;
  // Clusters of more points are evenly subsampled to this many before recognition (the
  // recogniser thins to its 4 mm voxel leaf anyway; a dense scan has ~10 points per voxel).
  int max_recognition_points = 20000;
  // A cluster whose accepted hypotheses leave at least this fraction (and
  // segmentation.min_cluster_points raw points) unexplained is recognised again on the
  // remainder (0: never).
  double remainder_fraction = 0.3;
  // Each connected part of a cluster's remainder (what its accepted hypotheses leave
  // unexplained; parts by the segmentation's clustering distance) that holds at least this
  // fraction of the cluster's points is recognised on its own too, whether or not the whole
  // remainder reaches remainder_fraction (0: never): an object against a larger one that
  // explains most of their cluster, its points mixed in the remainder with what the larger
  // one leaves of its own surface (a banana against a cracker box: 26% of the cluster
  // unexplained, the banana 21% of it, in one part). YCB tables (20 scenes, seed 1): 73 → 74
  // of 81 objects found, precision 100% either way (seed 301: 72 of 78 either way);
  // procedural tables, seeds 301–1101: 367 → 370 of 431 objects of the right class, 4 more
  // detections (one of a wrong class), clutter 108 of 108 either way. Tried first, parts of
  // any size (min_cluster_points): what a large object leaves of its own surface was then
  // accepted as small objects (3 on one scene). 0.1 (was 0.15): an upright glass touching a
  // large box's edge was 13.8% of their cluster, neither part nor remainder (held-out seed
  // 2601, scene 11). Procedural tables, held-out seeds 2301–5401: 1285 → 1289 of 1502
  // classes, 5501–7001: 632 → 635 of 758, development seeds 301–2201: 657 → 658 of 769,
  // none lost; clutter rejected as before (381/384, 190/192, 188/192).
  double remainder_part_fraction = 0.1;
  // A cluster no hypothesis explains gets, for its first twin_hypotheses hypotheses (by
  // model fit), their half-turn twins about each principal axis of the model, ICP-refined
  // on the cluster (0: none). A view-based search confuses an object with its other side
  // when the two look alike (a drill on its left or right side).
  int twin_hypotheses = 2;
  // Each cluster whose recognition ranks a class first with at least
  // verification.min_class_probability gets its best posed suggestion of that class tried
  // with the class's other database models — the sibling_hypotheses of them whose size
  // (height and extents along the table, in that pose) is nearest the cluster's — each
  // ICP-refined on the cluster, after the first verification (0: none). An unseen instance
  // is fitted badly, or only passably, by the database instance whose views it resembles
  // most when that one is larger or smaller (a wide bowl posed as a narrow one); the
  // procedural classes share one frame per class (axis up, base at the origin), so the
  // pose carries over. Classes of one model (an instance database): nothing to try. Seeds
  // 301, 401, 501, 601 of eval --table --procedural (16-instance database): class recall
  // 110 → 118 of 189, clutter rejected 48 of 48 either way.
  int sibling_hypotheses = 3;
  // The same suggestion also with its model scaled per axis to the cluster's size (the
  // extent of its points along each model axis in that pose; the height from the table),
  // each factor within [1/max_scale, max_scale], ICP-refined on the cluster (≤ 1: none).
  // Unseen instances larger or smaller than every database instance of their class (a box
  // 19 cm deep against database boxes of 5–9 cm). Reported with its `scale`. Only for
  // classes of two or more database models (a class of one model is an instance, whose
  // size is known: the YCB tables, where scaled models only took wrong poses).
  double max_scale = 1.6;
  // Each cluster's best posed suggestion of every class its recognition gives at least
  // roll_min_class_probability, when that model is nearly a body of revolution with a part
  // off it (a mug's or a saucepan's handle: recogniser/near_symmetry.h, at least
  // roll_min_asymmetry of its surface moves when turned), is also tried turned about that
  // axis in roll_steps equal steps (the turns other than none), each ICP-refined on the
  // cluster and put down on the table (≤ 1: none). The pose search fits the body and
  // leaves the handle's turn to chance: it lands where the scan saw free space, and the
  // model is rejected or loses to a glass.
  int roll_steps = 6;
  double roll_min_class_probability = 0.15;
  double roll_min_asymmetry = 0.02;
  // Those turns are not taken on a cluster already explained: an accepted hypothesis of
  // the class its recognition ranks first, less than other_class_remainder of its points
  // left unexplained — no part of it for another class's turned model to put a handle on
  // (a turn can then at most tie). true: turned there too. Procedural tables, 16 seeds:
  // the same objects in 190 of 192 scans and the same totals (class recall 331/384 and
  // 447/534, detections, clutter); `table_latency_bench` (database instances, which the
  // first looks explain) scene recognition 100 → 70 ms median.
  bool roll_explained_clusters = false;
  // A cluster no hypothesis explains (or with a remainder of at least remainder_fraction)
  // is split along its concave seams
  // (recogniser/convex_segmentation.h) and its split_segments largest segments are
  // recognised alone (0: never): touching objects clustered together, whose mixed
  // points no single view matches.
  int split_segments = 4;
  // Such a cluster of at least three segments is also split in two along its weakest seam
  // (WeakestSeamSplit, recogniser/convex_segmentation.h), each side of at least this
  // fraction of its points, and both sides are recognised alone (0: never): two touching
  // objects of several convex segments each (figurines), whom no one segment separates.
  double seam_split_fraction = 0.2;
  // A cluster no hypothesis explains is also recognised joined with each cluster that
  // comes within join_distance of it (metres; 0: never): one object cut in two by a
  // shadow (a mug's handle apart from its body) or by another object in front of it.
  double join_distance = 0.025;
  // Also join with each such cluster the unexplained remainder (at least
  // remainder_fraction) of a cluster partly explained: an object touching another (clustered
  // with it) whose other part a shadow cut off (classic tables, seed 301, scene 14: spot's
  // body touching cheburashka, its legs apart).
  bool join_remainders = true;
  // Farther apart than join_distance but within join_gap (metres; ≤ join_distance: never),
  // the two are joined too when the camera did not see through the gap between them (at
  // most join_max_seen of the segment between their nearest points has a scene point
  // behind it in its line of sight; points of the two themselves there tell nothing) and
  // one model could span both: a wine glass whose stem was too thin to scan, a bottle
  // whose shoulder the projector grazed, a lying wine glass whose bowl and foot the
  // segmentation cut from its stem (procedural tables, six seeds: 240 → 242 of 287
  // objects of the right class with the parts' own points not counted, 243 with fewer
  // than three other samples taken as unseen; clutter 72 of 72 throughout).
  double join_gap = 0.1;
  double join_max_seen = 0.35;
  // Two unexplained clusters joined also get the size looks of their joined recognition's
  // first class — its siblings (sibling_hypotheses) and the suggestion scaled (max_scale),
  // sized to the joined points: an unseen instance in two parts (a standing wine glass
  // whose bowl floats over its foot, the stem unscanned; a saucepan cut from its handle)
  // that no database model of its class fits as it is. Not for a cluster joined with an
  // accepted object's points (that object had its size looks on its own cluster; a
  // sibling stretched over it and its neighbour displaced a half-hidden mug), unless
  // object_join_size_looks. Procedural tables, six seeds: 239 → 240 of 287 objects of the
  // right class with the siblings, 241 with the scaled models too; clutter 71 of 72
  // throughout.
  bool join_size_looks = true;
  // ... and a cluster joined with an accepted object's points when the joined recognition
  // ranks another class first than that object's: the part that made the difference
  // (a mug's handle the segmentation cut off its body, taken for a glass; a can's cluster
  // with a neighbour's part) may belong to an instance of that class that no database
  // model fits as it is. Procedural tables, development seeds 301–2201: 656 → 658 of 769.
  bool object_join_size_looks = true;
  // The same size looks for a cluster's remainder and convex segments (split_segments)
  // recognised alone: an unseen instance touching another object, clustered with it.
  // Procedural tables, six seeds: 241 → 242 of 287 (a glass standing against a bowl,
  // found on its segment), one more detection of a wrong class (272 detections, 242 of
  // them right), clutter 71 of 72 either way.
  bool part_size_looks = true;
  // Upright looks: the source of the size looks (the best posed suggestion of the first
  // class), when its class has several database models (an instance's own views fit it:
  // on the YCB tables the unrefined upright pose only took the place of sharper ones) and
  // its model's axis of near symmetry is a model axis posed within
  // upright_max_tilt_deg of the table normal (a glass, a can, a wine glass standing), is
  // also tried stood exactly upright on the standing axis of the points (the vertical line
  // their normals, projected onto the table, meet: near_symmetry.h StandingAxisPoint) and
  // put down on the table; and the class's models, stood there too, scaled to the points'
  // height and to their radius profile about that axis, the sibling_hypotheses + 1 whose
  // profiles fit best — no ICP: axis and table fix a standing body of revolution. The pose
  // search fits an unseen instance on the database instance's views, which may lean or
  // float (a wine glass fitted to its bowl, its stem through free space: 47% of its
  // visible surface in front of the scan). Procedural tables, six seeds: 242 → 243 of 287
  // objects of the right class, clutter 71 of 72 either way. 0: none.
  double upright_max_tilt_deg = 30.0;
  // Rounds of these second looks (remainders, twins, segments, joins), each round on the
  // scene verification of the one before, until a round adds nothing.
  int second_look_rounds = 2;
  ConvexSegmentationOptions split;
  // Backdrop: a cluster whose points lie within backdrop_plane_distance of one plane
  // (at least backdrop_planar_fraction of them) and that spans more than
  // backdrop_extent_factor × the largest database model's diameter is a wall, a
  // backdrop or a shelf side behind the table, not an object: it is left out of
  // recognition (SceneRecognitionResult::background). 0: no such test.
  double backdrop_planar_fraction = 0.8;
  double backdrop_extent_factor = 1.2;
  double backdrop_plane_distance = 0.006;
  // Voxel leaf of the scene points the verification explains, and of the model surface
  // samples (union of the model's database views), metres.
  double scene_leaf = 0.003;
  double model_leaf = 0.003;
  void Check() const;  // throws sope::Error naming the invalid value
};

struct RecognisedObject {
  // The cluster's recognition with the accepted hypothesis first (its pose put down on
  // the table); the other suggestions are the cluster's other candidates.
  RecognitionResult recognition;
  int cluster = -1;        // into SceneRecognitionResult::segmentation.clusters
  std::vector<int> indices;  // input cloud points it explains (its segment), increasing
  double visible_fraction = 0.0;  // of its camera-facing surface, fitting scene points
  double snap_m = 0.0;     // the shift along the table normal the plane prior applied
  // Per-axis scale of the model (model frame, about its centre) that fits the object:
  // ones unless a scaled hypothesis (SceneRecognitionOptions::max_scale) was accepted.
  Eigen::Vector3d scale = Eigen::Vector3d::Ones();
  HypothesisEvidence evidence;
  bool verified = true;    // accepted by the scene verification
  // Accepted at class level only (HypothesisEvidence::class_level): an instance of the
  // class not in the database; recognition.best() is the nearest database instance.
  bool class_level = false;
  const Suggestion& best() const { return recognition.best(); }
};

struct UnknownObject {
  int cluster = -1;
  std::vector<int> indices;  // input cloud points no accepted hypothesis explains
  Eigen::Vector3f centroid = Eigen::Vector3f::Zero();
  // The rejected best guess (empty when the recogniser refused the cluster or gave none).
  std::string guess_class, guess_model;
  double guess_score = 0.0;
  // The scene verification's evidence on the cluster's best-fitting hypothesis and the
  // rule it failed (RejectionReason); empty when there was no hypothesis.
  double guess_model_fit = 0.0, guess_local_explained = 0.0, guess_violations = 0.0;
  std::string rejected_by;
};

struct SceneTimings {  // milliseconds, wall clock
  double segment = 0.0;
  double recognise = 0.0;  // every cluster (and remainder) through Recogniser::Recognise
  double verify = 0.0;
  double total = 0.0;
};

struct SceneRecognitionResult {
  TableSegmentation segmentation;
  std::vector<RecognisedObject> objects;  // verified, best score first
  std::vector<UnknownObject> unknown;     // clusters (or remainders) nothing explains
  // Clusters taken for a backdrop (SceneRecognitionOptions::backdrop_planar_fraction),
  // removed from segmentation.clusters before recognition.
  std::vector<ObjectCluster> background;
  int hypotheses = 0;                     // verified together
  SceneTimings timing;
  bool empty() const { return objects.empty(); }
};

// Which acceptance rule of the scene verification `evidence` failed, e.g. "model fit 0.52 <
// 0.60"; "gain (…)" when it passed the fit tests but the global selection left it out;
// empty when it was accepted.
std::string RejectionReason(const HypothesisEvidence& evidence,
                            const SceneVerificationOptions& options);

// One JSON line (DESIGN.md "Recognition result"): the best object's recognition result at
// the top level (RecognitionResultToJson; no object: "recognised": false, no class), and
// "objects": [each the per-object result fields plus "points", "visible_fraction",
// "verified", "match_level" ("instance" or "class"), "cluster", "snap_m"], "unknown": [{"points", "centroid", "guess"}], "table":
// {"found", "normal", "offset_m", "inliers"}, "clusters", "background": [{"points",
// "centroid"}], and the scene's timings
// ("scene_ms": segment, recognise, verify, total).
std::string SceneRecognitionResultToJson(const SceneRecognitionResult& result);

// A few lines: each object (class, model, score, points, centre) and the unknown ones.
std::string SceneBriefReport(const SceneRecognitionResult& result);

class SceneRecogniser {
 public:
  // Keeps a reference: `database` must outlive it.
  explicit SceneRecogniser(const Database& database);
  ~SceneRecogniser();
  const Database& database() const { return database_; }

  // Throws sope::Error on invalid options and on the clouds SegmentTable refuses (a
  // non-finite point, fewer than 3 points); no table or nothing on it is an empty result.
  // Safe to call concurrently.
  SceneRecognitionResult Recognise(const PointCloud& cloud,
                                   const SceneRecognitionOptions& options = {}) const;

  // The model's surface sample (union of its database views, voxel-thinned at `leaf`,
  // model frame, with normals); built once per model and leaf.
  const PointCloud& ModelSurface(int model, double leaf) const;
  // The outward unit normals (model frame) of the faces the model can rest on: the
  // statically stable facets of the convex hull of ModelSurface(model, leaf) for the
  // hull's centroid (core/convex_hull.h); empty when the hull is degenerate. Built once.
  const std::vector<Eigen::Vector3d>& RestingNormals(int model, double leaf) const;
  // The model's axis of near rotational symmetry (FindNearSymmetryAxis on
  // ModelSurface(model, leaf), tolerance 1.5 leaves). Built once.
  const NearSymmetryAxis& SymmetryAxis(int model, double leaf) const;
  // Builds the three above for every model at `options`' model leaf (what a first
  // recognition would otherwise build for the models it meets), until `stop` is set. Safe
  // on another thread while Recognise runs: the scan-and-recognise loop warms up during its
  // first capture.
  void WarmUp(const SceneRecognitionOptions& options,
              const std::atomic<bool>* stop = nullptr) const;

 private:
  struct Cache;
  const Database& database_;
  Recogniser recogniser_;
  std::unique_ptr<Cache> cache_;
};

}  // namespace sope
