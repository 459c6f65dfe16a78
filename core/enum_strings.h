// Enum ↔ text from one table per enum: the names a flag or a file uses are written once,
// next to the enum, and ToString / FromString (with the error naming the bad text and the
// accepted ones) follow from it.
//
//   enum class CoarseSearch { kKBest, kRadius };
//   template <> struct EnumTable<CoarseSearch> {
//     static constexpr const char* kWhat = "coarse search";
//     static constexpr EnumName<CoarseSearch> kNames[] = {{CoarseSearch::kKBest, "kbest"},
//                                                        {CoarseSearch::kRadius, "radius"}};
//   };
//   EnumToString(CoarseSearch::kRadius) == "radius";
//   EnumFromString<CoarseSearch>("kbest") == CoarseSearch::kKBest;
//   EnumFromString<CoarseSearch>("x") throws "unknown coarse search 'x' (expected kbest or radius)".
#pragma once

#include <iterator>
#include <string>
#include <type_traits>

#include "core/error.h"

namespace sope {

template <class E>
struct EnumName {
  E value;
  const char* name;
};

// Specialise for each enum: kWhat (what the enum names, for messages) and kNames.
template <class E>
struct EnumTable;

// True for enums with an EnumTable.
template <class E, class = void>
struct HasEnumTable : std::false_type {};
template <class E>
struct HasEnumTable<E, std::void_t<decltype(EnumTable<E>::kNames)>> : std::true_type {};

template <class E>
std::string EnumToString(E value) {
  for (const EnumName<E>& entry : EnumTable<E>::kNames) {
    if (entry.value == value) return entry.name;
  }
  return "unknown";
}

// "a, b or c".
template <class E>
std::string EnumChoices() {
  std::string text;
  const size_t n = std::size(EnumTable<E>::kNames);
  for (size_t i = 0; i < n; ++i) {
    if (i > 0) text += i + 1 == n ? " or " : ", ";
    text += EnumTable<E>::kNames[i].name;
  }
  return text;
}

// Throws sope::Error naming `text` and the accepted names.
template <class E>
E EnumFromString(const std::string& text) {
  for (const EnumName<E>& entry : EnumTable<E>::kNames) {
    if (text == entry.name) return entry.value;
  }
  SOPE_THROW("unknown {} '{}' (expected {})", EnumTable<E>::kWhat, text, EnumChoices<E>());
}

}  // namespace sope
