// The column lists of docs/trace-format.md, read from the spec itself, so the
// tests of the trace writer and the device log compare against one source.
#pragma once

#include <gtest/gtest.h>

#include <fstream>
#include <string>
#include <vector>

namespace hrt_test {

// The first cells of the table under the heading `heading` (a "## " line) of
// docs/trace-format.md, backticks stripped: the spec's column list.
inline std::vector<std::string> trace_spec_columns(const std::string& heading) {
  std::ifstream in(HRT_SOURCE_DIR "/../docs/trace-format.md");
  EXPECT_TRUE(in.good()) << "docs/trace-format.md not found";
  std::string line;
  bool in_section = false, in_table = false;
  int rows = 0;
  std::vector<std::string> out;
  while (std::getline(in, line)) {
    if (line.rfind("## ", 0) == 0) {
      if (in_section) break;
      in_section = line == heading;
      continue;
    }
    if (!in_section) continue;
    if (line.rfind("|", 0) != 0) {
      if (in_table) break;
      continue;
    }
    in_table = true;
    if (++rows <= 2) continue;  // the table's header and its |---| line
    const size_t a = line.find('`'), b = line.find('`', a + 1);
    EXPECT_NE(b, std::string::npos) << line;
    if (b == std::string::npos) continue;
    out.push_back(line.substr(a + 1, b - a - 1));
  }
  return out;
}

}  // namespace hrt_test
