// JSON read/write of an options struct from its field descriptions (core/options.h):
// every field under its name ("a.b" → {"a": {"b": …}}), numbers and bools as JSON numbers
// and bools, enums by their names. Reading keeps the current value of a field the JSON
// does not hold (files written before the field existed still read).
#pragma once

#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/error.h"
#include "core/options.h"

namespace sope {

namespace internal {
// The object that holds the last component of `name` ("a.b.c" → j["a"]["b"]), created
// when `create` (the const overload: nullptr when absent). `key` receives the last component.
inline nlohmann::json* JsonParent(nlohmann::json* j, const std::string& name, bool create,
                                  std::string* key) {
  size_t start = 0;
  for (size_t dot = name.find('.'); dot != std::string::npos; dot = name.find('.', start)) {
    const std::string part = name.substr(start, dot - start);
    if (!create && (!j->is_object() || !j->contains(part))) return nullptr;
    j = &(*j)[part];
    start = dot + 1;
  }
  *key = name.substr(start);
  return j;
}
inline const nlohmann::json* JsonParent(const nlohmann::json& j, const std::string& name,
                                        std::string* key) {
  const nlohmann::json* parent = &j;
  size_t start = 0;
  for (size_t dot = name.find('.'); dot != std::string::npos; dot = name.find('.', start)) {
    const std::string part = name.substr(start, dot - start);
    if (!parent->is_object() || !parent->contains(part)) return nullptr;
    parent = &parent->at(part);
    start = dot + 1;
  }
  *key = name.substr(start);
  return parent;
}
}  // namespace internal

template <class S>
nlohmann::json FieldsToJson(const S& options, const std::vector<OptionField<S>>& fields) {
  nlohmann::json j = nlohmann::json::object();
  for (const OptionField<S>& field : fields) {
    std::string key;
    nlohmann::json& parent = *internal::JsonParent(&j, field.name, true, &key);
    const void* p = field.Address(options);
    switch (field.type) {
      case FieldType::kBool: parent[key] = *static_cast<const bool*>(p); break;
      case FieldType::kInt: parent[key] = *static_cast<const int*>(p); break;
      case FieldType::kInt64: parent[key] = *static_cast<const int64_t*>(p); break;
      case FieldType::kUint64: parent[key] = *static_cast<const uint64_t*>(p); break;
      case FieldType::kFloat: parent[key] = *static_cast<const float*>(p); break;
      case FieldType::kDouble: parent[key] = *static_cast<const double*>(p); break;
      case FieldType::kEnum: parent[key] = field.to_text(options); break;
    }
  }
  return j;
}

// Sets the fields `j` holds; throws sope::Error naming a field of the wrong JSON type or
// an unknown enum name.
template <class S>
void FieldsFromJson(const nlohmann::json& j, const std::vector<OptionField<S>>& fields,
                    S* options) {
  for (const OptionField<S>& field : fields) {
    std::string key;
    const nlohmann::json* parent = internal::JsonParent(j, field.name, &key);
    if (parent == nullptr || !parent->is_object() || !parent->contains(key)) continue;
    const nlohmann::json& value = parent->at(key);
    void* p = field.address(*options);
    const bool ok = field.type == FieldType::kEnum   ? value.is_string()
                    : field.type == FieldType::kBool ? value.is_boolean()
                                                     : value.is_number();
    SOPE_CHECK(ok, "option '{}' has a JSON {} value, expected a {}", field.name,
               value.type_name(),
               field.type == FieldType::kEnum   ? "string"
               : field.type == FieldType::kBool ? "boolean"
                                                : "number");
    switch (field.type) {
      case FieldType::kBool: *static_cast<bool*>(p) = value.get<bool>(); break;
      case FieldType::kInt: *static_cast<int*>(p) = value.get<int>(); break;
      case FieldType::kInt64: *static_cast<int64_t*>(p) = value.get<int64_t>(); break;
      case FieldType::kUint64: *static_cast<uint64_t*>(p) = value.get<uint64_t>(); break;
      case FieldType::kFloat: *static_cast<float*>(p) = value.get<float>(); break;
      case FieldType::kDouble: *static_cast<double*>(p) = value.get<double>(); break;
      case FieldType::kEnum: field.from_text(*options, value.get<std::string>()); break;
    }
  }
}

}  // namespace sope
