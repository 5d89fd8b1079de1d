// Guard of hrt's JSON output: nlohmann-json prints NaN and infinity as
// `null`, which a consumer would read as "no value" although it is a bug
// upstream (e.g. an overflow in a computation). The commands check their
// document with first_non_finite before printing and end as an internal
// error (exit 70) when it finds one. Header-only (used by cmd_*.cpp and the
// tests).
#pragma once

#include <cmath>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

namespace hrt_cli {

// Path ("a/2/b") of the first non-finite number of `doc` in document order,
// or "" when every number is finite. Iterative (an explicit stack), so any
// nesting depth is safe.
template <typename Json>
std::string first_non_finite(const Json& doc) {
  std::vector<std::pair<const Json*, std::string>> stack{{&doc, std::string()}};
  while (!stack.empty()) {
    auto [v, path] = std::move(stack.back());
    stack.pop_back();
    if (v->is_number_float()) {
      if (!std::isfinite(v->template get<double>())) return path;
    } else if (v->is_array()) {
      // Pushed in reverse, so the first element is visited first.
      for (size_t i = v->size(); i-- > 0;)
        stack.emplace_back(&(*v)[i], path.empty() ? std::to_string(i) : path + "/" + std::to_string(i));
    } else if (v->is_object()) {
      std::vector<std::pair<const Json*, std::string>> members;
      for (auto it = v->begin(); it != v->end(); ++it)
        members.emplace_back(&it.value(), path.empty() ? it.key() : path + "/" + it.key());
      stack.insert(stack.end(), members.rbegin(), members.rend());
    }
  }
  return "";
}

}  // namespace hrt_cli
