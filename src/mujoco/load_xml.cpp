// mj_loadXML behind a C++ boundary: MuJoCo 2.2.2's XML parser and compiler are C++, and an
// exception they do not catch themselves (std::bad_alloc under a memory limit, say) must not
// unwind into Rust. Any exception becomes a null model and a message in `error`.
#include <cstdio>
#include <exception>
#include <new>

#include <mujoco/mujoco.h>

extern "C" mjModel* mjsafe_load_xml(const char* filename, const mjVFS* vfs, char* error, int error_sz) {
  try {
    return mj_loadXML(filename, vfs, error, error_sz);
  } catch (const std::bad_alloc&) {
    std::snprintf(error, error_sz, "out of memory while MuJoCo compiled the model");
  } catch (const std::exception& e) {
    std::snprintf(error, error_sz, "MuJoCo's compiler failed: %s", e.what());
  } catch (...) {
    std::snprintf(error, error_sz, "MuJoCo's compiler failed with an exception");
  }
  return nullptr;
}
