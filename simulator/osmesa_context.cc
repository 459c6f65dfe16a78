// GL_GLEXT_PROTOTYPES before any GL header: Mesa's libOSMesa exports the whole GL API, so
// core-profile entry points are called directly.
#define GL_GLEXT_PROTOTYPES 1
#include "simulator/osmesa_context.h"

#include <GL/osmesa.h>
#include <GL/glext.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <string>

#include "core/error.h"

namespace sope {
namespace internal {
namespace {

constexpr char kVertexShader[] = R"(#version 330 core
layout(location = 0) in vec3 position_in_model;
uniform mat4 clip_from_model;
void main() { gl_Position = clip_from_model * vec4(position_in_model, 1.0); }
)";

// gl_PrimitiveID counts the triangles of the current draw call from 0.
constexpr char kFragmentShader[] = R"(#version 330 core
uniform uint first_id;
layout(location = 0) out uint triangle_id;
void main() { triangle_id = first_id + uint(gl_PrimitiveID); }
)";

// Framebuffers kept alive per size (camera and projector views alternate in SetScene).
constexpr size_t kMaxCachedFramebuffers = 4;

GLuint CompileShader(GLenum type, const char* source) {
  const GLuint shader = glCreateShader(type);
  glShaderSource(shader, 1, &source, nullptr);
  glCompileShader(shader);
  GLint ok = GL_FALSE;
  glGetShaderiv(shader, GL_COMPILE_STATUS, &ok);
  if (ok != GL_TRUE) {
    std::array<char, 2048> log{};
    glGetShaderInfoLog(shader, static_cast<GLsizei>(log.size()), nullptr, log.data());
    glDeleteShader(shader);
    SOPE_THROW("OSMesa: shader compilation failed: {}", log.data());
  }
  return shader;
}

}  // namespace

Eigen::Matrix4d ClipFromDevice(const PinholeView& view, double near, double far) {
  const double w = view.width, h = view.height;
  Eigen::Matrix4d clip_from_device = Eigen::Matrix4d::Zero();
  clip_from_device(0, 0) = 2.0 * view.fx / w;
  clip_from_device(0, 2) = (2.0 * (view.cx + 0.5) - w) / w;
  clip_from_device(1, 1) = 2.0 * view.fy / h;
  clip_from_device(1, 2) = (2.0 * (view.cy + 0.5) - h) / h;
  clip_from_device(2, 2) = (far + near) / (far - near);
  clip_from_device(2, 3) = -2.0 * far * near / (far - near);
  clip_from_device(3, 2) = 1.0;
  return clip_from_device;
}

struct IdRasteriser::Impl {
  struct Framebuffer {
    int width = 0, height = 0;
    GLuint framebuffer = 0, color = 0, depth = 0;
  };
  struct MeshBuffers {
    GLuint vertex_array = 0, vertices = 0, indices = 0;
    GLsizei index_count = 0;
    uint32_t first_id = 0;
  };

  OSMesaContext context = nullptr;
  // OSMesa needs a default colour buffer to make the context current; we draw into FBOs.
  std::array<uint8_t, 4 * 16 * 16> default_buffer{};
  GLuint program = 0;
  GLint clip_from_model_location = -1;
  GLint first_id_location = -1;
  int max_size = 0;
  std::vector<Framebuffer> framebuffers;  // most recently used last
  std::vector<MeshBuffers> meshes;

  void MakeCurrent() {
    if (OSMesaGetCurrentContext() == context) return;
    if (!OSMesaMakeCurrent(context, default_buffer.data(), GL_UNSIGNED_BYTE, 16, 16)) {
      SOPE_THROW("OSMesa: cannot make the context current");
    }
  }

  void DeleteMeshes() {
    for (MeshBuffers& mesh : meshes) {
      glDeleteVertexArrays(1, &mesh.vertex_array);
      glDeleteBuffers(1, &mesh.vertices);
      glDeleteBuffers(1, &mesh.indices);
    }
    meshes.clear();
  }

  const Framebuffer& FramebufferOfSize(int width, int height) {
    for (size_t i = 0; i < framebuffers.size(); ++i) {
      if (framebuffers[i].width == width && framebuffers[i].height == height) {
        std::rotate(framebuffers.begin() + i, framebuffers.begin() + i + 1, framebuffers.end());
        return framebuffers.back();
      }
    }
    if (framebuffers.size() >= kMaxCachedFramebuffers) {
      Framebuffer& old = framebuffers.front();
      glDeleteFramebuffers(1, &old.framebuffer);
      glDeleteRenderbuffers(1, &old.color);
      glDeleteRenderbuffers(1, &old.depth);
      framebuffers.erase(framebuffers.begin());
    }
    Framebuffer fb;
    fb.width = width;
    fb.height = height;
    glGenRenderbuffers(1, &fb.color);
    glBindRenderbuffer(GL_RENDERBUFFER, fb.color);
    glRenderbufferStorage(GL_RENDERBUFFER, GL_R32UI, width, height);
    glGenRenderbuffers(1, &fb.depth);
    glBindRenderbuffer(GL_RENDERBUFFER, fb.depth);
    glRenderbufferStorage(GL_RENDERBUFFER, GL_DEPTH_COMPONENT32F, width, height);
    glGenFramebuffers(1, &fb.framebuffer);
    glBindFramebuffer(GL_FRAMEBUFFER, fb.framebuffer);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, fb.color);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, fb.depth);
    const GLenum status = glCheckFramebufferStatus(GL_FRAMEBUFFER);
    if (status != GL_FRAMEBUFFER_COMPLETE) {
      glDeleteFramebuffers(1, &fb.framebuffer);
      glDeleteRenderbuffers(1, &fb.color);
      glDeleteRenderbuffers(1, &fb.depth);
      SOPE_THROW("OSMesa: {}x{} id framebuffer incomplete (status 0x{:x})", width, height, status);
    }
    framebuffers.push_back(fb);
    return framebuffers.back();
  }
};

IdRasteriser::IdRasteriser() : impl_(std::make_unique<Impl>()) {
  const int attributes[] = {OSMESA_FORMAT,
                            OSMESA_RGBA,
                            OSMESA_DEPTH_BITS,
                            0,
                            OSMESA_STENCIL_BITS,
                            0,
                            OSMESA_ACCUM_BITS,
                            0,
                            OSMESA_PROFILE,
                            OSMESA_CORE_PROFILE,
                            OSMESA_CONTEXT_MAJOR_VERSION,
                            3,
                            OSMESA_CONTEXT_MINOR_VERSION,
                            3,
                            0};
  impl_->context = OSMesaCreateContextAttribs(attributes, nullptr);
  if (impl_->context == nullptr) {
    SOPE_THROW(
        "OSMesa cannot create an OpenGL 3.3 core-profile context (is Mesa's "
        "libOSMesa with a Gallium driver such as llvmpipe installed?)");
  }
  try {
    impl_->MakeCurrent();
    const GLuint vertex_shader = CompileShader(GL_VERTEX_SHADER, kVertexShader);
    const GLuint fragment_shader = CompileShader(GL_FRAGMENT_SHADER, kFragmentShader);
    impl_->program = glCreateProgram();
    glAttachShader(impl_->program, vertex_shader);
    glAttachShader(impl_->program, fragment_shader);
    glLinkProgram(impl_->program);
    glDeleteShader(vertex_shader);
    glDeleteShader(fragment_shader);
    GLint ok = GL_FALSE;
    glGetProgramiv(impl_->program, GL_LINK_STATUS, &ok);
    if (ok != GL_TRUE) {
      std::array<char, 2048> log{};
      glGetProgramInfoLog(impl_->program, static_cast<GLsizei>(log.size()), nullptr, log.data());
      SOPE_THROW("OSMesa: shader program link failed: {}", log.data());
    }
    impl_->clip_from_model_location = glGetUniformLocation(impl_->program, "clip_from_model");
    impl_->first_id_location = glGetUniformLocation(impl_->program, "first_id");
    GLint renderbuffer_size = 0;
    glGetIntegerv(GL_MAX_RENDERBUFFER_SIZE, &renderbuffer_size);
    GLint viewport_dims[2] = {0, 0};
    glGetIntegerv(GL_MAX_VIEWPORT_DIMS, viewport_dims);
    impl_->max_size = std::min({renderbuffer_size, viewport_dims[0], viewport_dims[1]});
    if (glGetError() != GL_NO_ERROR || impl_->max_size <= 0) {
      SOPE_THROW("OSMesa: GL error while setting up the id rasteriser");
    }
  } catch (...) {
    if (impl_->program != 0) glDeleteProgram(impl_->program);
    OSMesaDestroyContext(impl_->context);
    throw;
  }
}

IdRasteriser::~IdRasteriser() {
  if (impl_ == nullptr || impl_->context == nullptr) return;
  try {
    impl_->MakeCurrent();
    impl_->DeleteMeshes();
    for (Impl::Framebuffer& fb : impl_->framebuffers) {
      glDeleteFramebuffers(1, &fb.framebuffer);
      glDeleteRenderbuffers(1, &fb.color);
      glDeleteRenderbuffers(1, &fb.depth);
    }
    glDeleteProgram(impl_->program);
  } catch (const Error&) {
    // The context is destroyed below with everything it owns.
  }
  OSMesaMakeCurrent(nullptr, nullptr, 0, 0, 0);
  OSMesaDestroyContext(impl_->context);
}

int IdRasteriser::max_size() const { return impl_->max_size; }

void IdRasteriser::SetMeshes(const std::vector<const TriangleMesh*>& meshes) {
  impl_->MakeCurrent();
  impl_->DeleteMeshes();
  uint32_t next_id = 1;
  for (const TriangleMesh* mesh : meshes) {
    Impl::MeshBuffers buffers;
    buffers.first_id = next_id;
    buffers.index_count = static_cast<GLsizei>(3 * mesh->faces.size());
    next_id += static_cast<uint32_t>(mesh->faces.size());
    glGenVertexArrays(1, &buffers.vertex_array);
    glBindVertexArray(buffers.vertex_array);
    glGenBuffers(1, &buffers.vertices);
    glBindBuffer(GL_ARRAY_BUFFER, buffers.vertices);
    static_assert(sizeof(Eigen::Vector3f) == 3 * sizeof(float), "packed vertices");
    static_assert(sizeof(Eigen::Vector3i) == 3 * sizeof(GLuint), "packed faces");
    glBufferData(GL_ARRAY_BUFFER,
                 static_cast<GLsizeiptr>(mesh->vertices.size() * sizeof(Eigen::Vector3f)),
                 mesh->vertices.data(), GL_STATIC_DRAW);
    glEnableVertexAttribArray(0);
    glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 0, nullptr);
    glGenBuffers(1, &buffers.indices);
    glBindBuffer(GL_ELEMENT_ARRAY_BUFFER, buffers.indices);
    glBufferData(GL_ELEMENT_ARRAY_BUFFER,
                 static_cast<GLsizeiptr>(mesh->faces.size() * sizeof(Eigen::Vector3i)),
                 mesh->faces.data(), GL_STATIC_DRAW);
    glBindVertexArray(0);
    impl_->meshes.push_back(buffers);
  }
  if (glGetError() != GL_NO_ERROR) SOPE_THROW("OSMesa: GL error while uploading meshes");
}

void IdRasteriser::Render(const PinholeView& view, const std::vector<Rigid3d>& device_from_model,
                          double near, double far, cv::Mat* ids) {
  SOPE_CHECK(view.width > 0 && view.height > 0 && view.width <= impl_->max_size &&
                 view.height <= impl_->max_size,
             "id view {}x{} exceeds the OSMesa framebuffer limit {}", view.width, view.height,
             impl_->max_size);
  SOPE_CHECK(device_from_model.size() == impl_->meshes.size(),
             "id rasteriser: {} poses for {} meshes", device_from_model.size(),
             impl_->meshes.size());
  SOPE_CHECK(near > 0.0 && far > near, "id rasteriser: invalid clip range [{}, {}]", near, far);
  impl_->MakeCurrent();
  const Impl::Framebuffer& fb = impl_->FramebufferOfSize(view.width, view.height);
  glBindFramebuffer(GL_FRAMEBUFFER, fb.framebuffer);
  glViewport(0, 0, view.width, view.height);
  glDisable(GL_CULL_FACE);
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LESS);
  glDepthMask(GL_TRUE);
  const GLuint zero_id[4] = {0, 0, 0, 0};
  const GLfloat far_depth = 1.0f;
  glClearBufferuiv(GL_COLOR, 0, zero_id);
  glClearBufferfv(GL_DEPTH, 0, &far_depth);
  glUseProgram(impl_->program);
  const Eigen::Matrix4d clip_from_device = ClipFromDevice(view, near, far);
  for (size_t k = 0; k < impl_->meshes.size(); ++k) {
    const Impl::MeshBuffers& mesh = impl_->meshes[k];
    const Eigen::Matrix4f clip_from_model =
        (clip_from_device * device_from_model[k].ToMatrix()).cast<float>();
    glUniformMatrix4fv(impl_->clip_from_model_location, 1, GL_FALSE, clip_from_model.data());
    glUniform1ui(impl_->first_id_location, mesh.first_id);
    glBindVertexArray(mesh.vertex_array);
    glDrawElements(GL_TRIANGLES, mesh.index_count, GL_UNSIGNED_INT, nullptr);
  }
  glBindVertexArray(0);
  ids->create(view.height, view.width, CV_32SC1);
  glPixelStorei(GL_PACK_ALIGNMENT, 4);
  glReadBuffer(GL_COLOR_ATTACHMENT0);
  glReadPixels(0, 0, view.width, view.height, GL_RED_INTEGER, GL_UNSIGNED_INT, ids->data);
  const GLenum error = glGetError();
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
  if (error != GL_NO_ERROR) SOPE_THROW("OSMesa: GL error 0x{:x} while rasterising ids", error);
}

}  // namespace internal
}  // namespace sope
