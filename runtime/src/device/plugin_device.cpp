// PluginDevice (hrt/device.h): a device from a shared library implementing
// hrt/device_plugin.h (docs/device-plugins.md), loaded with dlopen.
//
// Two guards stand between the plugin and the runtime:
//   - the file is checked before dlopen (a regular file within
//     kMaxPluginBytes, an ELF header of this machine, every header and
//     segment within the file): dlopen maps the segments, and touching a page
//     past the end of a truncated file raises SIGBUS inside the loader, which
//     no error path can catch;
//   - every call into the plugin runs on one worker thread of the device and
//     the caller waits for it with a deadline (kPlugin*DeadlineMs): a plugin
//     that blocks can then fault the device (fault()) but never stop the
//     device thread, so the loop still ramps down and the session still ends.
#include <dlfcn.h>
#include <elf.h>
#include <fcntl.h>
#include <linux/futex.h>
#include <pthread.h>
#include <sched.h>
#include <signal.h>
#include <sys/stat.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

#include "hrt/device.h"
#include "hrt/device_plugin.h"
#include "hrt/files.h"

namespace hrt {
namespace {

constexpr size_t kErrorSize = 512;

// A plugin's message as one line: terminated, newlines folded, never empty.
std::string plugin_message(char* buf) {
  buf[kErrorSize - 1] = '\0';
  std::string s(buf);
  for (char& c : s)
    if (c == '\n' || c == '\r') c = ' ';
  return s.empty() ? "(no message)" : s;
}

std::string dl_message() {
  const char* e = dlerror();
  return e ? e : "(no dlerror message)";
}

DeviceInfo convert(const hrt_device_info& c, const std::string& what) {
  DeviceInfo info;
  info.name = std::string(c.name, strnlen(c.name, sizeof c.name));
  if (info.name.empty()) info.name = "plugin";
  auto dof = [&](const char* key, int v) {
    if (v != 3 && v != 6) throw DeviceError(what + ": info: " + key + " " + std::to_string(v) + " (3 or 6)");
    return v;
  };
  auto positive = [&](const char* key, double v) {
    if (!(std::isfinite(v) && v > 0))
      throw DeviceError(what + ": info: " + key + " " + std::to_string(v) + " (finite, > 0)");
    return v;
  };
  info.dof_sensed = dof("dof_sensed", c.dof_sensed);
  info.dof_actuated = dof("dof_actuated", c.dof_actuated);
  for (int i = 0; i < 3; ++i) info.workspace[i] = positive("workspace", c.workspace[i]);
  info.max_force = positive("max_force", c.max_force);
  info.max_torque = positive("max_torque", c.max_torque);
  info.max_stiffness = positive("max_stiffness", c.max_stiffness);
  info.max_angular_stiffness = positive("max_angular_stiffness", c.max_angular_stiffness);
  return info;
}

// ---------------------------------------------------------------------------
// The file, before dlopen
// ---------------------------------------------------------------------------

// The ELF machine and byte order of this build: a plugin for another machine
// is refused with its name instead of dlopen's "wrong ELF class" riddle.
#if defined(__x86_64__)
constexpr uint16_t kHostMachine = EM_X86_64;
#elif defined(__aarch64__)
constexpr uint16_t kHostMachine = EM_AARCH64;
#elif defined(__riscv) && __riscv_xlen == 64
constexpr uint16_t kHostMachine = EM_RISCV;
#elif defined(__powerpc64__)
constexpr uint16_t kHostMachine = EM_PPC64;
#elif defined(__s390x__)
constexpr uint16_t kHostMachine = EM_S390;
#else
#error "plugin_device.cpp: add this machine's ELF e_machine (elf.h)"
#endif
static_assert(sizeof(void*) == 8, "plugins are checked as 64-bit ELF files");
#if __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
constexpr unsigned char kHostData = ELFDATA2LSB;
#else
constexpr unsigned char kHostData = ELFDATA2MSB;
#endif

std::string machine_name(uint16_t m) {
  switch (m) {
    case EM_X86_64: return "x86-64";
    case EM_386: return "32-bit x86";
    case EM_AARCH64: return "AArch64";
    case EM_ARM: return "32-bit ARM";
    case EM_RISCV: return "RISC-V";
    case EM_PPC64: return "64-bit PowerPC";
    case EM_S390: return "s390";
    default: return "machine " + std::to_string(m);
  }
}

// off + len, saturated: a corrupt header may hold offsets near 2^64.
uint64_t end_of(uint64_t off, uint64_t len) {
  uint64_t end = 0;
  return __builtin_add_overflow(off, len, &end) ? UINT64_MAX : end;
}

// Checks `path` before it is given to dlopen; throws DeviceError("WHAT: the
// problem"). The headers are read with pread, not mapped: reading past the
// end of a file returns short, where a mapping would raise SIGBUS.
void check_plugin_file(const std::string& path, const std::string& what) {
  try {
    check_input_file(path, kMaxPluginBytes, what);
  } catch (const InputFileError& e) {
    // The same words as dlopen's message for a missing file, which users
    // (and their scripts) already know.
    if (e.kind == InputFileError::Kind::missing)
      throw DeviceError(what + ": cannot load: " + path +
                        ": cannot open shared object file: No such file or directory");
    throw DeviceError(e.what());
  }
  // O_NONBLOCK: a path swapped for a FIFO since the check must not block the
  // open; the fstat below then refuses it.
  const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_NOCTTY | O_CLOEXEC);
  if (fd < 0) throw DeviceError(what + ": cannot read: " + std::strerror(errno));
  struct Closer {
    int fd;
    ~Closer() { ::close(fd); }
  } closer{fd};
  struct stat st{};
  if (::fstat(fd, &st) != 0) throw DeviceError(what + ": cannot read: " + std::strerror(errno));
  if (!S_ISREG(st.st_mode)) throw DeviceError(what + ": is no longer a regular file (it changed while being checked)");
  const uint64_t size = static_cast<uint64_t>(st.st_size);
  if (size > kMaxPluginBytes)
    throw DeviceError(what + ": " + std::to_string(size) + " bytes, more than the limit of " +
                      std::to_string(kMaxPluginBytes) + " bytes for this file");
  const std::string has = ", the file has " + std::to_string(size) + " bytes";
  // Reads [off, off + len) whole or says why not.
  auto read_at = [&](void* buf, uint64_t len, uint64_t off, const std::string& part) {
    size_t got = 0;
    while (got < len) {
      const ssize_t n = ::pread(fd, static_cast<char*>(buf) + got, len - got, static_cast<off_t>(off + got));
      if (n < 0 && errno == EINTR) continue;
      if (n < 0) throw DeviceError(what + ": cannot read " + part + ": " + std::strerror(errno));
      if (n == 0) throw DeviceError(what + ": truncated: " + part + " ends at byte " + std::to_string(off + len) + has);
      got += static_cast<size_t>(n);
    }
  };

  Elf64_Ehdr h{};
  read_at(&h, std::min<uint64_t>(size, sizeof h), 0, "the ELF header");
  if (size < SELFMAG || std::memcmp(h.e_ident, ELFMAG, SELFMAG) != 0)
    throw DeviceError(what + ": not a shared library (no ELF magic at its start)");
  if (size <= EI_DATA)
    throw DeviceError(what + ": truncated: the ELF header ends at byte " + std::to_string(sizeof h) + has);
  if (h.e_ident[EI_CLASS] != ELFCLASS64)
    throw DeviceError(what + ": " + (h.e_ident[EI_CLASS] == ELFCLASS32 ? "a 32-bit" : "an unknown class of") +
                      " ELF file; this runtime loads 64-bit plugins only");
  if (h.e_ident[EI_DATA] != kHostData)
    throw DeviceError(what + ": an ELF file of the other byte order than this machine's");
  if (size < sizeof h)
    throw DeviceError(what + ": truncated: the ELF header ends at byte " + std::to_string(sizeof h) + has);
  if (h.e_type != ET_DYN)
    throw DeviceError(what + ": not a shared library (ELF type " + std::to_string(h.e_type) +
                      (h.e_type == ET_EXEC  ? ": an executable"
                       : h.e_type == ET_REL ? ": an object file, link it with -shared"
                                            : "") +
                      ")");
  if (h.e_machine != kHostMachine)
    throw DeviceError(what + ": built for " + machine_name(h.e_machine) + ", this runtime runs on " +
                      machine_name(kHostMachine));

  // Program headers: what dlopen maps. A segment past the end of the file is
  // the SIGBUS of a truncated copy.
  if (h.e_phnum == 0) throw DeviceError(what + ": no program headers: not a loadable shared library");
  if (h.e_phentsize != sizeof(Elf64_Phdr))
    throw DeviceError(what + ": program headers of " + std::to_string(h.e_phentsize) + " bytes, not " +
                      std::to_string(sizeof(Elf64_Phdr)) + ": a corrupt ELF file");
  const uint64_t ph_bytes = uint64_t{h.e_phnum} * h.e_phentsize;
  if (end_of(h.e_phoff, ph_bytes) > size)
    throw DeviceError(what + ": truncated: the program headers end at byte " +
                      std::to_string(end_of(h.e_phoff, ph_bytes)) + has);
  std::vector<Elf64_Phdr> ph(h.e_phnum);
  read_at(ph.data(), ph_bytes, h.e_phoff, "the program headers");
  for (size_t i = 0; i < ph.size(); ++i) {
    const uint64_t end = end_of(ph[i].p_offset, ph[i].p_filesz);
    if (end > size)
      throw DeviceError(what + ": truncated: segment " + std::to_string(i) +
                        (ph[i].p_type == PT_DYNAMIC ? " (the dynamic section)" : "") + " ends at byte " +
                        std::to_string(end) + has);
  }

  // Section headers: dlopen does not read them, but a table cut short says
  // the file was cut (it is usually the last thing in the file).
  if (h.e_shoff != 0) {
    if (h.e_shentsize != sizeof(Elf64_Shdr))
      throw DeviceError(what + ": section headers of " + std::to_string(h.e_shentsize) + " bytes, not " +
                        std::to_string(sizeof(Elf64_Shdr)) + ": a corrupt ELF file");
    uint64_t count = h.e_shnum;
    if (count == 0) {  // more than 0xff00 sections: the count is in section 0's sh_size
      if (end_of(h.e_shoff, sizeof(Elf64_Shdr)) > size)
        throw DeviceError(what + ": truncated: the section headers start at byte " + std::to_string(h.e_shoff) + has);
      Elf64_Shdr s0{};
      read_at(&s0, sizeof s0, h.e_shoff, "the section headers");
      count = s0.sh_size;
    }
    const uint64_t sh_end =
        count > size / sizeof(Elf64_Shdr) ? UINT64_MAX : end_of(h.e_shoff, count * sizeof(Elf64_Shdr));
    if (sh_end > size)
      throw DeviceError(what + ": truncated: the section headers end at byte " + std::to_string(sh_end) + has);
  }
}

// ---------------------------------------------------------------------------
// Calls into the plugin, on its worker thread
// ---------------------------------------------------------------------------

enum class Call : uint32_t { none, create, info, open, close, destroy, read, write, quit };

const char* call_name(Call c) {
  switch (c) {
    case Call::create: return "create";
    case Call::info: return "info";
    case Call::open: return "open";
    case Call::close: return "close";
    case Call::destroy: return "destroy";
    case Call::read: return "read";
    case Call::write: return "write";
    default: return "?";
  }
}

int deadline_ms(Call c) {
  switch (c) {
    case Call::read: return kPluginReadDeadlineMs;
    case Call::write: return kPluginWriteDeadlineMs;
    case Call::open: return kPluginOpenDeadlineMs;
    default: return kPluginCallDeadlineMs;
  }
}

static_assert(sizeof(std::atomic<uint32_t>) == sizeof(uint32_t) && std::atomic<uint32_t>::is_always_lock_free,
              "a futex word must be a plain 32-bit integer");

long futex(std::atomic<uint32_t>& word, int op, uint32_t value, const timespec* timeout) noexcept {
  return ::syscall(SYS_futex, reinterpret_cast<uint32_t*>(&word), op, value, timeout, nullptr, 0);
}

int64_t monotonic_ns() noexcept {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return int64_t{ts.tv_sec} * 1000000000 + ts.tv_nsec;
}

}  // namespace

// Everything the worker thread touches lives here, so that on a stall the
// Impl can be leaked whole (the worker may come back from the plugin at any
// time later, or never, and must find its memory still there).
struct PluginDevice::Impl {
  std::string what;    // "plugin PATH", the prefix of every message
  std::string config;  // create()'s argument, kept here: a stalled create may still read it
  void* library = nullptr;
  const hrt_device_plugin* table = nullptr;
  void* handle = nullptr;
  bool opened = false;

  // The handoff. One call at a time (the interface never overlaps them): the
  // caller writes the arguments below, then bumps `posted`; the worker runs
  // the call, writes the results, then sets `finished` to the same number.
  // Atomics and futex wait/wake instead of a mutex and a condition variable:
  // the caller's wait has a bound (FUTEX_WAIT's timeout) and shares no lock
  // with plugin code, so a plugin stuck in a call cannot hold anything the
  // device thread needs; and nothing here allocates, so read() and write()
  // stay fit for the device thread.
  alignas(64) std::atomic<uint32_t> posted{0};
  alignas(64) std::atomic<uint32_t> finished{0};
  uint32_t sequence = 0;                  // the caller's side: the last call posted
  std::atomic<Call> stalled{Call::none};  // the call that missed its deadline, for good
  std::thread worker;
  std::atomic<pid_t> worker_tid{0};
  bool priority_matched = false;  // the device thread's side (read/write)

  // The call in flight: arguments, then results.
  Call call = Call::none;
  double t = 0;
  double pose[7] = {0, 0, 0, 0, 0, 0, 1};
  uint32_t buttons = 0;
  int clutch = 0;
  double wrench[6] = {0, 0, 0, 0, 0, 0};
  hrt_device_info info{};
  char error[kErrorSize] = {0};
  int result = 0;
  void* created = nullptr;

  void start_worker() {
    // SIGINT and SIGTERM (Ctrl-C, the end of a session) are for the runtime's
    // handler on its own threads: never delivered into plugin code, which may
    // not expect EINTR. The new thread inherits the mask it is created with.
    sigset_t block, old;
    sigemptyset(&block);
    sigaddset(&block, SIGINT);
    sigaddset(&block, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &block, &old);
    try {
      worker = std::thread([this] { worker_main(); });
    } catch (const std::exception& e) {
      pthread_sigmask(SIG_SETMASK, &old, nullptr);
      throw DeviceError(what + ": cannot start its thread: " + e.what());
    }
    pthread_sigmask(SIG_SETMASK, &old, nullptr);
  }

  void worker_main() noexcept {
    worker_tid.store(static_cast<pid_t>(::syscall(SYS_gettid)));
    pthread_setname_np(pthread_self(), "hrt-plugin");
    uint32_t seen = 0;
    for (;;) {
      uint32_t now;
      while ((now = posted.load(std::memory_order_acquire)) == seen) futex(posted, FUTEX_WAIT_PRIVATE, seen, nullptr);
      seen = now;
      const Call c = call;
      run(c);
      finished.store(now, std::memory_order_release);
      futex(finished, FUTEX_WAKE_PRIVATE, 1, nullptr);
      if (c == Call::quit) return;
    }
  }

  void run(Call c) noexcept {
    switch (c) {
      case Call::create: created = table->create(config.c_str(), error, sizeof error); break;
      case Call::info: result = table->info(handle, &info, error, sizeof error); break;
      case Call::open: result = table->open(handle, error, sizeof error); break;
      case Call::close: table->close(handle); break;
      case Call::destroy: table->destroy(handle); break;
      case Call::read: result = table->read(handle, t, pose, &buttons, &clutch); break;
      case Call::write: table->write(handle, t, wrench); break;
      default: break;
    }
  }

  void post(Call c) noexcept {
    call = c;
    posted.store(++sequence, std::memory_order_release);
    futex(posted, FUTEX_WAKE_PRIVATE, 1, nullptr);
  }

  // Runs `c` on the worker and waits at most its deadline. false: a stall
  // (fault() says so from now on; nothing is called any more).
  bool call_plugin(Call c) noexcept {
    post(c);
    const uint32_t seq = sequence;
    const int64_t deadline = monotonic_ns() + int64_t{deadline_ms(c)} * 1000000;
    for (;;) {
      if (finished.load(std::memory_order_acquire) == seq) return true;
      const int64_t left = deadline - monotonic_ns();
      if (left <= 0) break;
      const timespec ts{static_cast<time_t>(left / 1000000000), static_cast<long>(left % 1000000000)};
      // Sleeps while `finished` still holds the previous call's number (every
      // earlier call finished: after a stall nothing is posted again).
      futex(finished, FUTEX_WAIT_PRIVATE, seq - 1, &ts);
    }
    stalled.store(c, std::memory_order_release);
    // A stuck plugin that spins must not compete with the runtime's threads
    // for a CPU (it may run at the device thread's SCHED_FIFO priority).
    // (tid 0 would mean the calling thread: only a worker that never started.)
    const sched_param idle{};
    if (const pid_t tid = worker_tid.load()) sched_setscheduler(tid, SCHED_IDLE, &idle);
    return false;
  }

  // Device thread, first read or write after open: the worker runs read()
  // and write() for the device thread, so it gets its scheduling (SCHED_FIFO
  // with --sched-fifo) -- one pair of syscalls, once.
  void match_caller_priority() noexcept {
    if (priority_matched) return;
    priority_matched = true;
    const int policy = sched_getscheduler(0);
    sched_param p{};
    if (policy < 0 || sched_getparam(0, &p) != 0) return;
    if ((policy & ~SCHED_RESET_ON_FORK) == SCHED_OTHER) return;
    // Without the right to, the worker keeps its own.
    if (const pid_t tid = worker_tid.load()) sched_setscheduler(tid, policy, &p);
  }

  std::string stall_message() const {
    const Call c = stalled.load(std::memory_order_acquire);
    if (c == Call::none) return {};
    const int ms = deadline_ms(c);
    const std::string limit =
        ms % 1000 == 0 && ms >= 1000 ? std::to_string(ms / 1000) + " s" : std::to_string(ms) + " ms";
    return what + ": " + call_name(c) + "() did not return within " + limit +
           " (stalled); the plugin is no longer called";
  }

  bool is_stalled() const noexcept { return stalled.load(std::memory_order_relaxed) != Call::none; }

  DeviceInfo query_info() {
    const DeviceInfo defaults;
    info = hrt_device_info{};
    std::strncpy(info.name, defaults.name.c_str(), sizeof info.name - 1);
    info.dof_sensed = defaults.dof_sensed;
    info.dof_actuated = defaults.dof_actuated;
    for (int i = 0; i < 3; ++i) info.workspace[i] = defaults.workspace[i];
    info.max_force = defaults.max_force;
    info.max_torque = defaults.max_torque;
    info.max_stiffness = defaults.max_stiffness;
    info.max_angular_stiffness = defaults.max_angular_stiffness;
    std::memset(error, 0, sizeof error);
    if (!call_plugin(Call::info)) throw DeviceError(stall_message());
    if (result != 0) throw DeviceError(what + ": info failed: " + plugin_message(error));
    return convert(info, what);
  }

  // destroy(), stop the worker, dlclose. After a stall nothing of that
  // happens: the plugin is not called again, the worker (perhaps still in the
  // plugin) is detached rather than joined, the library stays mapped (its
  // code may still be running); the owner then leaks this Impl.
  void unload() noexcept {
    if (handle && table && !is_stalled()) call_plugin(Call::destroy);
    if (is_stalled()) {
      // Nothing here is written any more: the stuck call may still read it.
      if (worker.joinable()) worker.detach();
      return;
    }
    handle = nullptr;
    if (worker.joinable()) {
      post(Call::quit);  // the worker is idle (the last call returned): it exits at once
      worker.join();
    }
    if (library) dlclose(library);
    library = nullptr;
    table = nullptr;
  }
};

PluginDevice::PluginDevice(const std::string& library_path, const std::string& config) : impl_(new Impl) {
  Impl& m = *impl_;
  m.what = "plugin " + library_path;
  m.config = config;
  check_plugin_file(library_path, m.what);
  // A name without a slash would make dlopen search the library path and
  // perhaps load another file than the one just checked.
  const std::string load_path = library_path.find('/') == std::string::npos ? "./" + library_path : library_path;
  // RTLD_NOW: a plugin built against a missing SDK symbol fails here, with the
  // symbol's name, instead of at its first call on the device thread.
  // RTLD_LOCAL: two plugins may both define helpers of the same name.
  m.library = dlopen(load_path.c_str(), RTLD_NOW | RTLD_LOCAL);
  if (!m.library) throw DeviceError(m.what + ": cannot load: " + dl_message());
  try {
    dlerror();
    void* entry = dlsym(m.library, HRT_DEVICE_PLUGIN_ENTRY);
    if (!entry)
      throw DeviceError(m.what + ": no entry symbol " HRT_DEVICE_PLUGIN_ENTRY " (" + dl_message() +
                        "): not an hrt device plugin (hrt/device_plugin.h)");
    hrt_device_plugin_entry_fn fn;
    static_assert(sizeof fn == sizeof entry, "function and data pointers differ in size");
    std::memcpy(&fn, &entry, sizeof fn);
    m.table = fn();
    if (!m.table) throw DeviceError(m.what + ": " HRT_DEVICE_PLUGIN_ENTRY "() returned NULL");
    if (m.table->abi_version != HRT_DEVICE_PLUGIN_ABI)
      throw DeviceError(m.what + ": plugin ABI version " + std::to_string(m.table->abi_version) +
                        ", this runtime needs " + std::to_string(HRT_DEVICE_PLUGIN_ABI) +
                        " (rebuild the plugin against this hrt/device_plugin.h)");
    if (m.table->struct_size < sizeof(hrt_device_plugin))
      throw DeviceError(m.what + ": function table of " + std::to_string(m.table->struct_size) + " bytes, ABI " +
                        std::to_string(HRT_DEVICE_PLUGIN_ABI) + " needs " + std::to_string(sizeof(hrt_device_plugin)));
    const struct {
      const char* name;
      bool present;
    } required[] = {{"create", m.table->create != nullptr},
                    {"destroy", m.table->destroy != nullptr},
                    {"info", m.table->info != nullptr},
                    {"read", m.table->read != nullptr},
                    {"write", m.table->write != nullptr}};
    for (const auto& r : required)
      if (!r.present) throw DeviceError(m.what + ": required function '" + r.name + "' is NULL in its table");
    m.start_worker();
    std::memset(m.error, 0, sizeof m.error);
    if (!m.call_plugin(Call::create)) throw DeviceError(m.stall_message());
    if (!m.created) throw DeviceError(m.what + ": create failed: " + plugin_message(m.error));
    m.handle = m.created;
    info_ = m.query_info();
  } catch (...) {
    m.unload();
    // Deliberately leaked after a stall: the worker may still be inside the
    // plugin and will write into this Impl if the call ever returns.
    if (m.is_stalled()) impl_.release();
    throw;
  }
}

PluginDevice::~PluginDevice() {
  close();
  impl_->unload();
  // Deliberately leaked after a stall (see unload()): the detached worker
  // still owns a view of this memory.
  if (impl_->is_stalled()) impl_.release();
}

std::string PluginDevice::fault() const { return impl_->stall_message(); }

void PluginDevice::open() {
  Impl& m = *impl_;
  if (m.opened) return;
  if (m.is_stalled()) throw DeviceError(m.stall_message());
  if (m.table->open) {
    std::memset(m.error, 0, sizeof m.error);
    if (!m.call_plugin(Call::open)) throw DeviceError(m.stall_message());
    if (m.result != 0) throw DeviceError(m.what + ": open failed: " + plugin_message(m.error));
  }
  m.opened = true;
  m.priority_matched = false;
  try {
    info_ = m.query_info();  // the model may be known only now
  } catch (...) {
    close();
    throw;
  }
}

void PluginDevice::close() {
  Impl& m = *impl_;
  if (!m.opened) return;
  m.opened = false;
  // A stalled plugin is not called again: its close() would most likely
  // wait on what the stuck call holds.
  if (m.table->close && !m.is_stalled()) m.call_plugin(Call::close);
}

bool PluginDevice::read(double t, DeviceSample& out) noexcept {
  Impl& m = *impl_;
  if (!m.opened || m.is_stalled()) return false;  // the interface promises read only between open and close
  m.match_caller_priority();
  m.t = t;
  const double rest[7] = {0, 0, 0, 0, 0, 0, 1};
  std::memcpy(m.pose, rest, sizeof rest);
  m.buttons = 0;
  m.clutch = 0;
  if (!m.call_plugin(Call::read) || m.result <= 0) return false;
  const double* pose = m.pose;
  for (int i = 0; i < 7; ++i)
    if (!std::isfinite(pose[i])) return false;
  Eigen::Quaterniond q(pose[6], pose[3], pose[4], pose[5]);
  const double norm = q.norm();
  if (norm < 1e-6) return false;
  out.pose.position = Vec3(pose[0], pose[1], pose[2]);
  out.pose.rotation = info_.dof_sensed == 3 ? Eigen::Quaterniond::Identity() : Eigen::Quaterniond(q.coeffs() / norm);
  out.buttons = m.buttons;
  out.clutch = m.clutch != 0;
  return true;
}

void PluginDevice::write(double t, const Vec6& wrench) noexcept {
  Impl& m = *impl_;
  if (!m.opened || m.is_stalled()) return;
  m.match_caller_priority();
  m.t = t;
  for (int i = 0; i < 6; ++i) m.wrench[i] = wrench[i];
  m.call_plugin(Call::write);
}

}  // namespace hrt
