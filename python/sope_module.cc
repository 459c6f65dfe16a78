// Python bindings (`import sope`, issue 15): a thin layer over the stable public entry
// points — frame sets, calibrations and clouds (core/), Decode (decoder/), Triangulate
// (calibration/), Database::Open and Recogniser::Recognise with default options
// (recogniser/), the virtual rig (simulator/). No algorithm lives here.
//
// Arrays: results are numpy views of the C++ buffers (zero copy): the buffer's owner (a
// cv::Mat or a PointCloud moved to the heap) is kept alive by a capsule that is the array's
// base. Inputs are copied once into C++ containers (a cv::Mat or a PointCloud) so their
// lifetime never depends on Python's. Long calls release the GIL.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <memory>
#include <string>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "calibration/triangulation.h"
#include "core/error.h"
#include "core/frame_set.h"
#include "core/mesh.h"
#include "core/point_cloud.h"
#include "core/rig_calibration.h"
#include "core/units.h"
#include "decoder/decoder.h"
#include "projector/patterns.h"
#include "recogniser/database.h"
#include "recogniser/recogniser.h"
#include "simulator/scene_builder.h"
#include "simulator/simulate_scan.h"
#include "simulator/virtual_rig.h"

namespace py = pybind11;

namespace sope {
namespace python {
namespace {

// ---- cv::Mat ↔ numpy --------------------------------------------------------------------

py::dtype DtypeOf(int depth) {
  switch (depth) {
    case CV_8U: return py::dtype::of<uint8_t>();
    case CV_16U: return py::dtype::of<uint16_t>();
    case CV_32S: return py::dtype::of<int32_t>();
    case CV_32F: return py::dtype::of<float>();
    case CV_64F: return py::dtype::of<double>();
  }
  SOPE_THROW("image depth {} has no numpy equivalent here", depth);
}

// A view of `mat` (shared, not copied): rows × cols [× channels].
py::object MatToArray(const cv::Mat& mat) {
  if (mat.empty()) return py::none();
  auto* owner = new cv::Mat(mat);  // shares the buffer (reference counted)
  py::capsule base(owner, [](void* p) { delete static_cast<cv::Mat*>(p); });
  std::vector<py::ssize_t> shape = {owner->rows, owner->cols};
  std::vector<py::ssize_t> strides = {static_cast<py::ssize_t>(owner->step[0]),
                                      static_cast<py::ssize_t>(owner->step[1])};
  if (owner->channels() > 1) {
    shape.push_back(owner->channels());
    strides.push_back(static_cast<py::ssize_t>(owner->elemSize1()));
  }
  return py::array(DtypeOf(owner->depth()), shape, strides, owner->data, base);
}

// A copy of a 2-D (or H×W×C) numpy array as a cv::Mat.
cv::Mat ArrayToMat(const py::array& input, const char* what) {
  const py::buffer_info info = input.request();
  SOPE_CHECK(info.ndim == 2 || info.ndim == 3, "{}: expected a 2-D (or H x W x C) array, got "
             "{} dimensions", what, info.ndim);
  int depth = -1;
  if (py::isinstance<py::array_t<uint8_t>>(input)) depth = CV_8U;
  if (py::isinstance<py::array_t<uint16_t>>(input)) depth = CV_16U;
  if (py::isinstance<py::array_t<int32_t>>(input)) depth = CV_32S;
  if (py::isinstance<py::array_t<float>>(input)) depth = CV_32F;
  if (py::isinstance<py::array_t<double>>(input)) depth = CV_64F;
  SOPE_CHECK(depth >= 0, "{}: unsupported dtype {}", what,
             std::string(py::str(input.dtype())));
  const int channels = info.ndim == 3 ? static_cast<int>(info.shape[2]) : 1;
  const py::array contiguous = py::array::ensure(input, py::array::c_style);
  const cv::Mat view(static_cast<int>(info.shape[0]), static_cast<int>(info.shape[1]),
                     CV_MAKETYPE(depth, channels), const_cast<void*>(contiguous.data()));
  return view.clone();
}

py::array_t<double> ToArray(const Eigen::MatrixXd& matrix) {
  py::array_t<double> array({matrix.rows(), matrix.cols()});
  auto view = array.mutable_unchecked<2>();
  for (Eigen::Index r = 0; r < matrix.rows(); ++r) {
    for (Eigen::Index c = 0; c < matrix.cols(); ++c) view(r, c) = matrix(r, c);
  }
  return array;
}

Eigen::MatrixXd FromArray(const py::array_t<double, py::array::forcecast>& array, int rows,
                          int cols, const char* what) {
  SOPE_CHECK(array.ndim() == 2 && array.shape(0) == rows && array.shape(1) == cols,
             "{}: expected a {}x{} array", what, rows, cols);
  Eigen::MatrixXd matrix(rows, cols);
  auto view = array.unchecked<2>();
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) matrix(r, c) = view(r, c);
  }
  return matrix;
}

py::array_t<double> PoseToArray(const Rigid3d& pose) { return ToArray(pose.ToMatrix()); }

Rigid3d PoseFromArray(const py::array_t<double, py::array::forcecast>& array, const char* what) {
  const Eigen::MatrixXd matrix = FromArray(array, 4, 4, what);
  return Rigid3d(matrix.topLeftCorner<3, 3>(), matrix.topRightCorner<3, 1>());
}

// ---- clouds -----------------------------------------------------------------------------

// Zero-copy (N, 3) views of a cloud's points / colours / normals (the cloud is moved to
// the heap and owned by the arrays' shared capsule).
py::dict CloudToDict(PointCloud cloud) {
  auto owner = std::make_shared<PointCloud>(std::move(cloud));
  auto* keep = new std::shared_ptr<PointCloud>(owner);
  py::capsule base(keep, [](void* p) { delete static_cast<std::shared_ptr<PointCloud>*>(p); });
  const py::ssize_t n = static_cast<py::ssize_t>(owner->size());
  py::dict result;
  result["points"] = py::array_t<float>({n, py::ssize_t{3}},
                                        {static_cast<py::ssize_t>(sizeof(Eigen::Vector3f)),
                                         static_cast<py::ssize_t>(sizeof(float))},
                                        owner->points.empty() ? nullptr
                                                              : owner->points[0].data(),
                                        base);
  result["colors"] = owner->HasColors()
                         ? py::object(py::array_t<uint8_t>(
                               {n, py::ssize_t{3}},
                               {static_cast<py::ssize_t>(sizeof(Color3ub)), py::ssize_t{1}},
                               owner->colors[0].data(), base))
                         : py::object(py::none());
  result["normals"] =
      owner->HasNormals()
          ? py::object(py::array_t<float>({n, py::ssize_t{3}},
                                          {static_cast<py::ssize_t>(sizeof(Eigen::Vector3f)),
                                           static_cast<py::ssize_t>(sizeof(float))},
                                          owner->normals[0].data(), base))
          : py::object(py::none());
  return result;
}

PointCloud CloudFromArrays(const py::array_t<float, py::array::forcecast>& points,
                           const py::object& colors, const py::object& normals) {
  SOPE_CHECK(points.ndim() == 2 && points.shape(1) == 3, "points: expected an (N, 3) array");
  PointCloud cloud;
  const auto p = points.unchecked<2>();
  cloud.points.resize(p.shape(0));
  for (py::ssize_t i = 0; i < p.shape(0); ++i) cloud.points[i] = {p(i, 0), p(i, 1), p(i, 2)};
  if (!colors.is_none()) {
    const auto c = py::array_t<uint8_t, py::array::forcecast>::ensure(colors);
    SOPE_CHECK(c && c.ndim() == 2 && c.shape(0) == p.shape(0) && c.shape(1) == 3,
               "colors: expected an (N, 3) uint8 array matching the points");
    const auto view = c.unchecked<2>();
    cloud.colors.resize(view.shape(0));
    for (py::ssize_t i = 0; i < view.shape(0); ++i) {
      cloud.colors[i] = {view(i, 0), view(i, 1), view(i, 2)};
    }
  }
  if (!normals.is_none()) {
    const auto n = py::array_t<float, py::array::forcecast>::ensure(normals);
    SOPE_CHECK(n && n.ndim() == 2 && n.shape(0) == p.shape(0) && n.shape(1) == 3,
               "normals: expected an (N, 3) array matching the points");
    const auto view = n.unchecked<2>();
    cloud.normals.resize(view.shape(0));
    for (py::ssize_t i = 0; i < view.shape(0); ++i) {
      cloud.normals[i] = {view(i, 0), view(i, 1), view(i, 2)};
    }
  }
  cloud.Check();
  return cloud;
}

// ---- correspondence maps ----------------------------------------------------------------

py::dict MapToDict(const CorrespondenceMap& map) {
  py::dict result;
  result["proj_x"] = MatToArray(map.proj_x);
  result["proj_y"] = MatToArray(map.proj_y);
  result["mask"] = MatToArray(map.mask);
  result["confidence"] = MatToArray(map.confidence);
  result["projector_width"] = map.projector_width;
  result["projector_height"] = map.projector_height;
  result["step_x"] = map.step_x;
  result["step_y"] = map.step_y;
  return result;
}

CorrespondenceMap MapFromDict(const py::dict& maps) {
  CorrespondenceMap map;
  SOPE_CHECK(maps.contains("mask") && maps.contains("projector_width") &&
                 maps.contains("projector_height"),
             "maps: expected the dict decode() returns (mask, proj_x/proj_y, projector_width, "
             "projector_height)");
  map.projector_width = maps["projector_width"].cast<int>();
  map.projector_height = maps["projector_height"].cast<int>();
  map.mask = ArrayToMat(maps["mask"].cast<py::array>(), "mask");
  SOPE_CHECK(map.mask.type() == CV_8UC1, "mask: expected uint8");
  const auto plane = [&](const char* key) {
    if (!maps.contains(key) || maps[key].is_none()) return cv::Mat();
    cv::Mat mat = ArrayToMat(maps[key].cast<py::array>(), key);
    SOPE_CHECK(mat.type() == CV_32FC1 && mat.size() == map.mask.size(),
               "{}: expected float32 of the mask's size", key);
    return mat;
  };
  map.proj_x = plane("proj_x");
  map.proj_y = plane("proj_y");
  map.confidence = plane("confidence");
  if (map.confidence.empty()) map.confidence = cv::Mat(map.mask.size(), CV_32FC1, 1.0f);
  if (maps.contains("step_x")) map.step_x = maps["step_x"].cast<float>();
  if (maps.contains("step_y")) map.step_y = maps["step_y"].cast<float>();
  return map;
}

// ---- calibration ------------------------------------------------------------------------

py::dict DeviceToDict(const CameraModel& model) {
  py::dict result;
  result["width"] = model.width;
  result["height"] = model.height;
  result["matrix"] = ToArray(model.matrix);
  result["distortion"] = model.distortion;
  return result;
}

py::dict CalibrationToDict(const RigCalibration& calibration) {
  py::dict result;
  result["camera"] = DeviceToDict(calibration.camera);
  result["projector"] = DeviceToDict(calibration.projector);
  result["proj_from_cam"] = PoseToArray(calibration.proj_from_cam);
  result["rms_camera_px"] = calibration.rms_camera_px;
  result["rms_projector_px"] = calibration.rms_projector_px;
  result["rms_stereo_px"] = calibration.rms_stereo_px;
  return result;
}

CameraModel DeviceFromDict(const py::dict& device, const char* what) {
  CameraModel model;
  model.width = device["width"].cast<int>();
  model.height = device["height"].cast<int>();
  model.matrix = FromArray(device["matrix"].cast<py::array_t<double, py::array::forcecast>>(),
                           3, 3, what);
  model.distortion = device["distortion"].cast<std::vector<double>>();
  return model;
}

RigCalibration CalibrationFromDict(const py::dict& dict) {
  for (const char* key : {"camera", "projector", "proj_from_cam"}) {
    SOPE_CHECK(dict.contains(key), "calibration: missing '{}'", key);
  }
  RigCalibration calibration;
  calibration.camera = DeviceFromDict(dict["camera"].cast<py::dict>(), "camera matrix");
  calibration.projector = DeviceFromDict(dict["projector"].cast<py::dict>(), "projector matrix");
  calibration.proj_from_cam = PoseFromArray(
      dict["proj_from_cam"].cast<py::array_t<double, py::array::forcecast>>(), "proj_from_cam");
  for (const char* key : {"rms_camera_px", "rms_projector_px", "rms_stereo_px"}) {
    if (!dict.contains(key)) continue;
    const double value = dict[key].cast<double>();
    if (std::string(key) == "rms_camera_px") calibration.rms_camera_px = value;
    if (std::string(key) == "rms_projector_px") calibration.rms_projector_px = value;
    if (std::string(key) == "rms_stereo_px") calibration.rms_stereo_px = value;
  }
  calibration.Check();
  return calibration;
}

// ---- frame sets -------------------------------------------------------------------------

py::object ManifestToPython(const FrameSetManifest& manifest) {
  return py::module_::import("json").attr("loads")(SerializeFrameSetManifest(manifest));
}

// ---- recognition ------------------------------------------------------------------------

py::dict SuggestionToDict(const Suggestion& suggestion) {
  py::dict result;
  result["class"] = suggestion.class_name;
  result["model"] = suggestion.model_name;
  result["view"] = suggestion.view;
  result["score"] = suggestion.score;
  result["theta_deg"] = RadToDeg(suggestion.viewpoint.theta);
  result["phi_deg"] = RadToDeg(suggestion.viewpoint.phi);
  result["pose"] = PoseToArray(suggestion.cam_from_model);  // X_cam = pose · X_model
  result["posed"] = suggestion.posed;
  result["refined"] = suggestion.refined;
  result["hamming_distance"] = suggestion.hamming_distance;
  result["fine_distance"] = suggestion.fine_distance;
  result["ranking_distance"] = suggestion.ranking_distance;
  return result;
}

}  // namespace

PYBIND11_MODULE(_sope, m) {
  m.doc() = "sope: structured-light scanning, object recognition and pose estimation";
  py::register_exception<Error>(m, "Error", PyExc_RuntimeError);

  // Frame sets.
  py::class_<FrameSet>(m, "FrameSet", "A structured-light capture: manifest + one image per frame")
      .def_property_readonly("manifest",
                             [](const FrameSet& set) { return ManifestToPython(set.manifest); },
                             "frames.json as a dict")
      .def_property_readonly("images",
                             [](const FrameSet& set) {
                               py::list images;
                               for (const cv::Mat& image : set.images) {
                                 images.append(MatToArray(image));
                               }
                               return images;
                             },
                             "The frames, numpy views (uint8 or uint16, camera size)")
      .def_property_readonly("white_color",
                             [](const FrameSet& set) { return MatToArray(set.white_color); })
      .def_readonly("directory", &FrameSet::directory)
      .def_static(
          "from_arrays",
          [](const py::object& manifest, const std::vector<py::array>& images) {
            FrameSet set;
            const std::string text = py::module_::import("json").attr("dumps")(manifest)
                                         .cast<std::string>();
            set.manifest = ParseFrameSetManifest(text, "manifest");
            for (const py::array& image : images) set.images.push_back(ArrayToMat(image, "image"));
            set.Check();
            return set;
          },
          py::arg("manifest"), py::arg("images"),
          "A frame set from a frames.json dict and its images (copied)")
      .def("__len__", [](const FrameSet& set) { return set.images.size(); });
  m.def("load_frame_set",
        [](const std::string& directory) {
          py::gil_scoped_release release;
          return LoadFrameSet(directory);
        },
        py::arg("directory"), "Reads DIR/frames.json and its images");
  m.def("save_frame_set",
        [](const std::string& directory, const FrameSet& set) {
          py::gil_scoped_release release;
          WriteFrameSet(directory, set);
        },
        py::arg("directory"), py::arg("frame_set"), "Writes PNGs + frames.json atomically");

  // Calibrations (dicts: camera/projector {width, height, matrix, distortion},
  // proj_from_cam 4x4 with X_proj = proj_from_cam · X_cam, metres).
  m.def("load_calibration",
        [](const std::string& path) { return CalibrationToDict(ReadRigCalibration(path)); },
        py::arg("path"));
  m.def("save_calibration",
        [](const std::string& path, const py::dict& calibration) {
          WriteRigCalibration(path, CalibrationFromDict(calibration));
        },
        py::arg("path"), py::arg("calibration"));

  // Clouds: dicts of (N, 3) arrays: points float32 metres, colors uint8 or None, normals.
  m.def("load_cloud",
        [](const std::string& path) {
          PointCloud cloud;
          {
            py::gil_scoped_release release;
            cloud = ReadPointCloud(path);
          }
          return CloudToDict(std::move(cloud));
        },
        py::arg("path"), "PLY or PCD → {'points', 'colors', 'normals'}");
  m.def("save_cloud",
        [](const std::string& path, const py::array_t<float, py::array::forcecast>& points,
           const py::object& colors, const py::object& normals, bool ascii) {
          const PointCloud cloud = CloudFromArrays(points, colors, normals);
          py::gil_scoped_release release;
          WritePointCloud(path, cloud, ascii ? PlyFormat::kAscii : PlyFormat::kBinaryLittleEndian);
        },
        py::arg("path"), py::arg("points"), py::arg("colors") = py::none(),
        py::arg("normals") = py::none(), py::arg("ascii") = false,
        "PLY (binary unless ascii) or PCD by the extension");

  // Decoding and triangulation.
  m.def("decode",
        [](const FrameSet& set, double min_contrast, double min_bit_contrast, int num_threads,
           const std::string& gray_subpixel, bool consistency) {
          DecoderOptions options;
          options.min_contrast = min_contrast;
          options.min_bit_contrast = min_bit_contrast;
          options.num_threads = num_threads;
          options.gray_subpixel = GraySubpixelFromString(gray_subpixel);
          options.consistency.enabled = consistency;
          options.Check();
          CorrespondenceMap map;
          {
            py::gil_scoped_release release;
            map = Decode(set, options);
          }
          return MapToDict(map);
        },
        py::arg("frame_set"), py::arg("min_contrast") = DecoderOptions().min_contrast,
        py::arg("min_bit_contrast") = DecoderOptions().min_bit_contrast,
        py::arg("num_threads") = 1, py::arg("gray_subpixel") = "edges",
        py::arg("consistency") = true,
        "Correspondence maps (Gray codes refined from the stripe edges unless "
        "gray_subpixel='off', and undecided pixels decoded from their neighbours unless "
        "consistency=False, as `sope decode`): {'proj_x', 'proj_y' (float32, NaN invalid), 'mask' (uint8), "
        "'confidence' (float32), 'projector_width', 'projector_height', 'step_x', 'step_y'}");
  m.def("triangulate",
        [](const py::dict& maps, const py::dict& calibration, const py::object& white) {
          const CorrespondenceMap map = MapFromDict(maps);
          const RigCalibration rig = CalibrationFromDict(calibration);
          const cv::Mat white_image =
              white.is_none() ? cv::Mat() : ArrayToMat(white.cast<py::array>(), "white");
          TriangulationResult result;
          {
            py::gil_scoped_release release;
            result = Triangulate(map, rig, white_image);
          }
          py::dict cloud = CloudToDict(std::move(result.cloud));
          return py::make_tuple(py::object(cloud["points"]), py::object(cloud["colors"]));
        },
        py::arg("maps"), py::arg("calibration"), py::arg("white") = py::none(),
        "(points (N, 3) float32 metres in the camera frame, colours (N, 3) uint8 or None)");

  // Recognition.
  py::class_<Database, std::shared_ptr<Database>>(m, "Database", "An opened .sopedb file")
      .def_static("open",
                  [](const std::string& path) {
                    std::unique_ptr<Database> db;
                    {
                      py::gil_scoped_release release;
                      db = Database::Open(path);
                    }
                    return std::shared_ptr<Database>(std::move(db));
                  },
                  py::arg("path"))
      .def_property_readonly("num_views", &Database::num_views)
      .def_property_readonly("num_models", &Database::num_models)
      .def_property_readonly("classes", &Database::classes)
      .def_property_readonly("models", [](const Database& db) {
        std::vector<std::string> names;
        for (const ModelRecord& model : db.models()) names.push_back(model.name);
        return names;
      });
  struct PyRecogniser {
    std::shared_ptr<Database> database;
    Recogniser recogniser;
    explicit PyRecogniser(std::shared_ptr<Database> db)
        : database(std::move(db)), recogniser(*database) {}
  };
  py::class_<PyRecogniser>(m, "Recogniser")
      .def(py::init<std::shared_ptr<Database>>(), py::arg("database"))
      .def(
          "recognise",
          [](const PyRecogniser& self, const py::array_t<float, py::array::forcecast>& points,
             int top) {
            const PointCloud cloud = CloudFromArrays(points, py::none(), py::none());
            RecognitionOptions options;
            options.top_k = top;
            options.Check();
            RecognitionResult result;
            {
              py::gil_scoped_release release;
              result = self.recogniser.Recognise(cloud, options);
            }
            py::list suggestions;
            for (const Suggestion& suggestion : result.suggestions) {
              suggestions.append(SuggestionToDict(suggestion));
            }
            return suggestions;
          },
          py::arg("points"), py::arg("top") = RecognitionOptions().top_k,
          "Suggestions, best first: dicts with class, model, view, score, theta_deg, phi_deg, "
          "pose (4x4 cam_from_model, metres), posed, refined, distances");

  // The virtual rig.
  m.def("default_rig", []() { return CalibrationToDict(DefaultRigCalibration()); });
  m.def("simulate",
        [](const std::string& mesh, const py::array_t<double, py::array::forcecast>& pose,
           const py::object& rig, double size, uint64_t seed) {
          const RigCalibration calibration =
              rig.is_none() ? DefaultRigCalibration() : CalibrationFromDict(rig.cast<py::dict>());
          const Rigid3d centre_pose = PoseFromArray(pose, "pose");
          SimulatedScan scan;
          {
            py::gil_scoped_release release;
            Placement placement;
            placement.rotation = centre_pose.rotation;
            placement.center_in_cam = centre_pose.translation;
            placement.size = size;
            Scene scene;
            scene.objects.push_back(PlaceObject(LoadMeshSpec(mesh), placement));
            SensorOptions sensor;
            sensor.seed = seed;
            VirtualRig virtual_rig(calibration, sensor);
            PatternOptions patterns;
            patterns.projector_width = calibration.projector.width;
            patterns.projector_height = calibration.projector.height;
            scan = SimulateScan(virtual_rig, scene, patterns);
          }
          py::dict truth;
          truth["depth"] = MatToArray(scan.ground_truth.depth);
          truth["proj_x"] = MatToArray(scan.ground_truth.proj_x);
          truth["proj_y"] = MatToArray(scan.ground_truth.proj_y);
          truth["lit"] = MatToArray(scan.ground_truth.lit);
          truth["object_id"] = MatToArray(scan.ground_truth.object_id);
          truth["cam_from_model"] = PoseToArray(scan.scene.objects.front().cam_from_model);
          truth["calibration"] = CalibrationToDict(scan.calibration);
          return py::make_tuple(std::move(scan.frames), truth);
        },
        py::arg("mesh"), py::arg("pose"), py::arg("rig") = py::none(), py::arg("size") = 0.0,
        py::arg("seed") = 1,
        "Renders the Gray-code sequence of `mesh` (a file or builtin:NAME) placed with `pose` "
        "(4x4: rotation and bounding-box centre in the camera frame, metres) on the virtual "
        "rig → (FrameSet, ground truth dict: depth, proj_x, proj_y, lit, object_id, "
        "cam_from_model, calibration). size > 0 scales the mesh to that diagonal (metres); "
        "seed: the sensor noise's seed (`sope simulate --seed`).");
}

}  // namespace python
}  // namespace sope
