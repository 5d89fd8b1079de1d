// Sets an environment variable for a scope and restores it (the GL tests
// force HRT_EGL_PLATFORM and HRT_GL_PROBE).
#pragma once

#include <cstdlib>
#include <string>

struct EnvGuard {
  std::string name, old;
  bool had;
  EnvGuard(const char* n, const char* v) : name(n) {
    const char* o = std::getenv(n);
    had = o != nullptr;
    if (had) old = o;
    setenv(n, v, 1);
  }
  ~EnvGuard() {
    if (had)
      setenv(name.c_str(), old.c_str(), 1);
    else
      unsetenv(name.c_str());
  }
};
