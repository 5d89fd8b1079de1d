// hrt_reliability_bundle DIR [PIECES] [SIDES]
//
// Writes the measurement bundle of docs/input-contract.md (validators' cost):
// the test writer's cube whose pieces.ply holds PIECES prisms over a SIDES-gon
// (defaults 200 and 512: 1024 vertices and 2044 faces each, the worst case of
// the convexity check per byte; 200 pieces make a 10 MB pieces.ply). Then
// `/usr/bin/time -f "%e s %M KB" hrt check DIR` and `hbake validate DIR`.
#include <cstdio>
#include <cstdlib>
#include <string>

#include "test_io_writer.h"

int main(int argc, char** argv) {
  if (argc < 2 || argc > 4) {
    std::fprintf(stderr, "usage: %s DIR [PIECES (200)] [SIDES (512)]\n", argv[0]);
    return 2;
  }
  const int pieces = argc > 2 ? std::atoi(argv[2]) : 200;
  const int sides = argc > 3 ? std::atoi(argv[3]) : 512;
  if (pieces < 1 || pieces > 100000 || sides < 3 || sides > 100000) {
    std::fprintf(stderr, "%s: PIECES must be in [1, 100000] and SIDES in [3, 100000]\n", argv[0]);
    return 2;
  }
  hrt_test::many_prism_bundle(argv[1], hrt_test::make_cube(), pieces, sides);
  std::printf("%s: %d prisms over a %d-gon\n", argv[1], pieces, sides);
  return 0;
}
