// One description per option field — name, member, doc, unit, valid range and (optionally)
// a CLI flag — from which the CLI binding (app/option_flags.h), the JSON read/write
// (core/options_json.h) and the range checks of an options struct's Check() follow, so
// an option is added, renamed or bounded in one place.
//
//   const std::vector<OptionField<CoarseOptions>>& CoarseOptions::Fields() {
//     static const std::vector<OptionField<CoarseOptions>> fields = {
//         Field(&CoarseOptions::flag_fraction, "flag_fraction", "Fraction of the database "
//               "flagged (kbest)").Above(0.0).AtMost(1.0).Flag("--flag-fraction"),
//         ...};
//     return fields;
//   }
//   void CoarseOptions::Check() const { CheckFields(*this, Fields(), "recognition: coarse."); }
//
// Nested structs: AppendNested(&fields, &Outer::inner, "inner", Inner::Fields()) gives the
// inner fields the names "inner.<name>" (JSON: an object "inner" holding them).
#pragma once

#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "core/enum_strings.h"
#include "core/error.h"

namespace sope {

enum class FieldType { kBool, kInt, kInt64, kUint64, kFloat, kDouble, kEnum };

template <class S>
struct OptionField {
  std::string name;  // JSON key; "a.b" for field b of the nested object a
  std::string flag;  // CLI flag ("--pose-models"; a bool "--no-x" clears it); empty: none
  std::string doc;
  std::string unit;  // "m", "rad", …; empty: dimensionless
  FieldType type = FieldType::kDouble;
  // Valid range (numbers; bools and enums are not range-checked). NaN is never valid.
  double min = -std::numeric_limits<double>::infinity();
  double max = std::numeric_limits<double>::infinity();
  bool min_open = false, max_open = false;
  // The member in an instance (cast to the type `type` names; enums: their own type).
  std::function<void*(S&)> address;
  // Enums: the value as its name, and set from a name (throws sope::Error naming it).
  std::function<std::string(const S&)> to_text;
  std::function<void(S&, const std::string&)> from_text;
  std::string choices;  // enums: "a, b or c"
  std::function<void(const S&, S*)> copy;  // copies this field from one instance to another

  // Builders.
  OptionField& Flag(std::string cli_flag) { flag = std::move(cli_flag); return *this; }
  OptionField& Unit(std::string text) { unit = std::move(text); return *this; }
  OptionField& AtLeast(double lo) { min = lo; min_open = false; return *this; }
  OptionField& Above(double lo) { min = lo; min_open = true; return *this; }
  OptionField& AtMost(double hi) { max = hi; max_open = false; return *this; }
  OptionField& Below(double hi) { max = hi; max_open = true; return *this; }
  OptionField& In(double lo, double hi) { return AtLeast(lo).AtMost(hi); }

  const void* Address(const S& s) const { return address(const_cast<S&>(s)); }
  bool IsNumber() const { return type != FieldType::kBool && type != FieldType::kEnum; }
  // The value of a number or bool field as a double.
  double Number(const S& s) const {
    const void* p = Address(s);
    switch (type) {
      case FieldType::kBool: return *static_cast<const bool*>(p) ? 1.0 : 0.0;
      case FieldType::kInt: return *static_cast<const int*>(p);
      case FieldType::kInt64: return static_cast<double>(*static_cast<const int64_t*>(p));
      case FieldType::kUint64: return static_cast<double>(*static_cast<const uint64_t*>(p));
      case FieldType::kFloat: return *static_cast<const float*>(p);
      case FieldType::kDouble: return *static_cast<const double*>(p);
      case FieldType::kEnum: break;
    }
    return std::numeric_limits<double>::quiet_NaN();
  }
  bool InRange(double v) const {
    if (std::isnan(v)) return false;
    if (min_open ? !(v > min) : !(v >= min)) return false;
    if (max_open ? !(v < max) : !(v <= max)) return false;
    return true;
  }
  // "in (0, 1]", "≥ 1", "< 3"…
  std::string RangeText() const {
    const bool has_min = std::isfinite(min), has_max = std::isfinite(max);
    if (has_min && has_max) {
      return fmt::format("in {}{}, {}{}", min_open ? "(" : "[", min, max, max_open ? ")" : "]");
    }
    if (has_min) return fmt::format("{} {}", min_open ? ">" : "≥", min);
    if (has_max) return fmt::format("{} {}", max_open ? "<" : "≤", max);
    return "a number";
  }
};

namespace internal {
template <class T>
constexpr FieldType FieldTypeOf() {
  if constexpr (std::is_same_v<T, bool>) return FieldType::kBool;
  else if constexpr (std::is_same_v<T, int>) return FieldType::kInt;
  else if constexpr (std::is_same_v<T, int64_t>) return FieldType::kInt64;
  else if constexpr (std::is_same_v<T, uint64_t>) return FieldType::kUint64;
  else if constexpr (std::is_same_v<T, float>) return FieldType::kFloat;
  else if constexpr (std::is_same_v<T, double>) return FieldType::kDouble;
  else {
    static_assert(std::is_enum_v<T> && HasEnumTable<T>::value,
                  "option fields are bool, int, int64_t, uint64_t, float, double or an enum "
                  "with an EnumTable");
    return FieldType::kEnum;
  }
}
}  // namespace internal

// The description of `member` of S, called `name`.
template <class S, class T>
OptionField<S> Field(T S::*member, std::string name, std::string doc) {
  OptionField<S> field;
  field.name = std::move(name);
  field.doc = std::move(doc);
  field.type = internal::FieldTypeOf<T>();
  field.address = [member](S& s) -> void* { return &(s.*member); };
  field.copy = [member](const S& from, S* to) { to->*member = from.*member; };
  if constexpr (std::is_enum_v<T>) {
    field.to_text = [member](const S& s) { return EnumToString(s.*member); };
    field.from_text = [member](S& s, const std::string& text) {
      s.*member = EnumFromString<T>(text);
    };
    field.choices = EnumChoices<T>();
  }
  return field;
}

// Appends the fields of `Outer::*member` (described by `inner`) as "prefix.<name>".
template <class Outer, class Inner>
void AppendNested(std::vector<OptionField<Outer>>* fields, Inner Outer::*member,
                  const std::string& prefix, const std::vector<OptionField<Inner>>& inner) {
  for (const OptionField<Inner>& f : inner) {
    OptionField<Outer> field;
    field.name = prefix + "." + f.name;
    field.flag = f.flag;
    field.doc = f.doc;
    field.unit = f.unit;
    field.type = f.type;
    field.min = f.min;
    field.max = f.max;
    field.min_open = f.min_open;
    field.max_open = f.max_open;
    field.choices = f.choices;
    field.address = [member, a = f.address](Outer& s) { return a(s.*member); };
    field.copy = [member, c = f.copy](const Outer& from, Outer* to) {
      c(from.*member, &(to->*member));
    };
    if (f.to_text) {
      field.to_text = [member, t = f.to_text](const Outer& s) { return t(s.*member); };
      field.from_text = [member, t = f.from_text](Outer& s, const std::string& text) {
        t(s.*member, text);
      };
    }
    fields->push_back(std::move(field));
  }
}

// Throws sope::Error "<prefix><name> must be <range>, got <value>" for the first number
// field outside its range (prefix e.g. "recognition: coarse.").
template <class S>
void CheckFields(const S& options, const std::vector<OptionField<S>>& fields,
                 const std::string& prefix) {
  for (const OptionField<S>& field : fields) {
    if (!field.IsNumber()) continue;
    const double value = field.Number(options);
    SOPE_CHECK(field.InRange(value), "{}{} must be {}, got {}", prefix, field.name,
               field.RangeText(), value);
  }
}

// The field called `name`, or nullptr.
template <class S>
const OptionField<S>* FindField(const std::vector<OptionField<S>>& fields,
                                const std::string& name) {
  for (const OptionField<S>& field : fields) {
    if (field.name == name) return &field;
  }
  return nullptr;
}

}  // namespace sope
