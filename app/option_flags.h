// CLI11 flags from option field descriptions (core/options.h): every field with a flag is
// bound directly to its member of `options` (numbers and enums as options with the
// current value shown as the default, bools as flags — "--no-x" clears the field).
#pragma once

#include <string>
#include <utility>
#include <vector>

#include <CLI/CLI.hpp>

#include "core/options.h"

namespace sope {
namespace cli {

template <class S>
struct BoundFlag {
  const OptionField<S>* field;
  CLI::Option* option;
};

template <class S>
std::vector<BoundFlag<S>> AddOptionFlags(CLI::App& app, S* options,
                                         const std::vector<OptionField<S>>& fields) {
  std::vector<BoundFlag<S>> bound;
  for (const OptionField<S>& field : fields) {
    if (field.flag.empty()) continue;
    std::string doc = field.doc;
    if (!field.unit.empty()) doc += ", " + field.unit;
    if (field.IsNumber()) doc += " (" + field.RangeText() + ")";
    void* p = field.address(*options);
    CLI::Option* option = nullptr;
    switch (field.type) {
      case FieldType::kBool:
        if (field.flag.rfind("--no-", 0) == 0) {
          bool* value = static_cast<bool*>(p);
          option = app.add_flag_callback(field.flag, [value] { *value = false; }, doc);
        } else {
          option = app.add_flag(field.flag, *static_cast<bool*>(p), doc);
        }
        break;
      case FieldType::kInt:
        option = app.add_option(field.flag, *static_cast<int*>(p), doc)->capture_default_str();
        break;
      case FieldType::kInt64:
        option = app.add_option(field.flag, *static_cast<int64_t*>(p), doc)->capture_default_str();
        break;
      case FieldType::kUint64:
        option =
            app.add_option(field.flag, *static_cast<uint64_t*>(p), doc)->capture_default_str();
        break;
      case FieldType::kFloat:
        option = app.add_option(field.flag, *static_cast<float*>(p), doc)->capture_default_str();
        break;
      case FieldType::kDouble:
        option = app.add_option(field.flag, *static_cast<double*>(p), doc)->capture_default_str();
        break;
      case FieldType::kEnum: {
        const OptionField<S>* f = &field;
        option = app.add_option_function<std::string>(
                        field.flag, [f, options](const std::string& text) {
                          f->from_text(*options, text);
                        },
                        doc + ": " + field.choices)
                     ->default_str(field.to_text(*options));
        break;
      }
    }
    bound.push_back({&field, option});
  }
  return bound;
}

// Copies the fields whose flag was given from `parsed` to `options` (flags bound to a
// scratch struct, applied over defaults chosen after parsing, e.g. a preset).
template <class S>
void ApplyGivenFlags(const std::vector<BoundFlag<S>>& bound, const S& parsed, S* options) {
  for (const BoundFlag<S>& b : bound) {
    if (b.option->count() > 0) b.field->copy(parsed, options);
  }
}

}  // namespace cli
}  // namespace sope
