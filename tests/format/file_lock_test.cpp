// The file-opening layer refuses what is not a regular file (without blocking on a FIFO),
// and io::FileLock keeps one writer per output: another process is refused naming the
// holder's PID, the lock goes with its holder however it ends, and one process may take
// its own lock twice. "Other processes" here are fork()ed children that talk over pipes.
#include "format/io/file_lock.h"

#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstring>
#include <filesystem>

#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "format/io/file.h"
#include "format/io/manifest.h"
#include "format/io/verifier.h"
#include "test_util.h"

namespace ltb {
namespace {

bool Contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

// ---- non-regular files ---------------------------------------------------------------

TEST(FileOpen, RefusesFifoWithoutWaitingForAWriter) {
  test::TempDir dir;
  const std::string fifo = dir.File("pipe.ltm");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0644), 0);
  // A blocking open would wait here for a writer that never comes (the test would hang).
  for (auto mode : {io::File::Mode::kRead, io::File::Mode::kReadWrite, io::File::Mode::kWriteDirect}) {
    auto f = io::File::Open(fifo, mode);
    ASSERT_FALSE(f.ok());
    EXPECT_EQ(f.status().code(), StatusCode::kInvalidArgument);
    EXPECT_TRUE(Contains(f.status().message(), fifo + ": is a FIFO (named pipe), not a regular file"))
        << f.status().message();
  }
  auto r = io::ContainerReader::Open(fifo);
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(Contains(r.status().message(), "FIFO")) << r.status().message();
  io::VerifyReport v = io::VerifyContainer(fifo);
  ASSERT_EQ(v.problems.size(), 1u);
  EXPECT_TRUE(Contains(v.problems[0], fifo + ": is a FIFO")) << v.problems[0];
  EXPECT_FALSE(io::LooksLikeManifest(fifo));
}

TEST(FileOpen, RefusesADirectoryAsADirectoryNotAsMissing) {
  test::TempDir dir;
  const std::string d = dir.File("sub.ltm");
  ASSERT_EQ(::mkdir(d.c_str(), 0755), 0);
  for (auto mode : {io::File::Mode::kRead, io::File::Mode::kReadWrite}) {
    auto f = io::File::Open(d, mode);
    ASSERT_FALSE(f.ok());
    EXPECT_EQ(f.status().code(), StatusCode::kInvalidArgument);
    EXPECT_TRUE(Contains(f.status().message(), d + ": is a directory, not a regular file")) << f.status().message();
  }
  Status s = io::RequireRegularFile(d);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_TRUE(Contains(s.message(), "is a directory")) << s.message();
}

TEST(FileOpen, RefusesDevicesAndSockets) {
  for (const char* dev : {"/dev/zero", "/dev/null"}) {
    auto f = io::File::Open(dev, io::File::Mode::kRead);
    ASSERT_FALSE(f.ok());
    EXPECT_TRUE(Contains(f.status().message(), std::string(dev) + ": is a character device")) << f.status().message();
    EXPECT_EQ(io::RequireRegularFile(dev).code(), StatusCode::kInvalidArgument);
  }
  test::TempDir dir;
  const std::string sock = dir.File("s.ltm");
  int fd = ::socket(AF_UNIX, SOCK_STREAM, 0);
  ASSERT_GE(fd, 0);
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  ASSERT_LT(sock.size(), sizeof addr.sun_path);
  std::memcpy(addr.sun_path, sock.c_str(), sock.size() + 1);
  ASSERT_EQ(::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
  auto f = io::File::Open(sock, io::File::Mode::kRead);
  ::close(fd);
  ASSERT_FALSE(f.ok());
  EXPECT_TRUE(Contains(f.status().message(), sock + ": is a socket")) << f.status().message();
}

TEST(FileOpen, MissingIsNotFoundAndRegularFilesOpen) {
  test::TempDir dir;
  const std::string p = dir.File("absent.ltm");
  EXPECT_EQ(io::File::Open(p, io::File::Mode::kRead).status().code(), StatusCode::kNotFound);
  EXPECT_EQ(io::RequireRegularFile(p).code(), StatusCode::kNotFound);
  auto c = io::File::Open(p, io::File::Mode::kCreateExclusive);
  ASSERT_TRUE(c.ok()) << c.status().message();
  // The descriptor is blocking again after the check (O_NONBLOCK cleared).
  EXPECT_EQ(::fcntl(c->fd(), F_GETFL) & O_NONBLOCK, 0);
  EXPECT_TRUE(io::RequireRegularFile(p).ok());
  auto r = io::File::Open(p, io::File::Mode::kRead);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(::fcntl(r->fd(), F_GETFL) & O_NONBLOCK, 0);
}

// ---- locks -------------------------------------------------------------------------------

// A child process that takes `output`'s lock (or opens a writer on it), reports on `ready`
// and holds it until told to go on `go`, then exits (with _exit: no release when `crash`).
struct Holder {
  pid_t pid = -1;
  int ready = -1, go = -1;

  static Holder Start(const std::string& output, bool writer, bool crash) {
    int r[2], g[2];
    EXPECT_EQ(::pipe(r), 0);
    EXPECT_EQ(::pipe(g), 0);
    Holder h;
    h.pid = ::fork();
    if (h.pid == 0) {
      ::close(r[0]);
      ::close(g[1]);
      char ok = 'n';
      {
        io::FileLock lock;
        io::ContainerWriter w;
        if (writer) {
          auto o = io::ContainerWriter::Open(output, test::MatrixMetadata(8, 4, format::Layout::kRows, 4));
          if (o.ok()) {
            w = std::move(o).value();
            ok = 'y';
          }
        } else {
          auto l = io::LockOutput(output);
          if (l.ok()) {
            lock = std::move(l).value();
            ok = 'y';
          }
        }
        (void)!::write(r[1], &ok, 1);
        char c;
        (void)!::read(g[0], &c, 1);
        if (crash) ::_exit(0);  // as a killed process: nothing released, the kernel drops the lock
      }
      ::_exit(0);
    }
    ::close(r[1]);
    ::close(g[0]);
    h.ready = r[0];
    h.go = g[1];
    char ok = 0;
    EXPECT_EQ(::read(h.ready, &ok, 1), 1);
    EXPECT_EQ(ok, 'y') << "the child could not take the lock";
    return h;
  }
  void Finish() {
    char c = 'x';
    (void)!::write(go, &c, 1);
    int status = 0;
    ::waitpid(pid, &status, 0);
    ::close(ready);
    ::close(go);
  }
};

TEST(FileLock, SecondProcessIsRefusedNamingTheHolder) {
  test::TempDir dir;
  const std::string out = dir.File("out.ltm");
  Holder h = Holder::Start(out, false, false);
  auto l = io::LockOutput(out);
  ASSERT_FALSE(l.ok());
  EXPECT_EQ(l.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_EQ(l.status().message(), out + " is in use by PID " + std::to_string(h.pid) +
                                      " (another ltbake writing it); wait for it or choose another output");
  EXPECT_EQ(io::LockHolderPid(io::OutputLockPath(out)), h.pid);
  h.Finish();
  // Released (and its file removed) when the holder ends.
  EXPECT_FALSE(std::filesystem::exists(io::OutputLockPath(out)));
  auto again = io::LockOutput(out);
  ASSERT_TRUE(again.ok()) << again.status().message();
  EXPECT_EQ(io::LockHolderPid(io::OutputLockPath(out)), ::getpid());
}

TEST(FileLock, DiesWithItsHolder) {
  test::TempDir dir;
  const std::string out = dir.File("out.ltm");
  Holder h = Holder::Start(out, false, true);
  EXPECT_FALSE(io::LockOutput(out).ok());
  h.Finish();  // exits without releasing: the file stays, naming a dead PID
  EXPECT_TRUE(std::filesystem::exists(io::OutputLockPath(out)));
  auto l = io::LockOutput(out);
  ASSERT_TRUE(l.ok()) << l.status().message();
  EXPECT_EQ(io::LockHolderPid(io::OutputLockPath(out)), ::getpid());
  l->Release();
  EXPECT_FALSE(std::filesystem::exists(io::OutputLockPath(out)));
}

TEST(FileLock, OneProcessMayTakeItsOwnLockAgain) {
  test::TempDir dir;
  const std::string out = dir.File("out.ltm");
  auto a = io::LockOutput(out);
  ASSERT_TRUE(a.ok()) << a.status().message();
  auto b = io::LockOutput(out);  // e.g. a stage holding its output while the writer opens it
  ASSERT_TRUE(b.ok()) << b.status().message();
  a->Release();
  EXPECT_TRUE(std::filesystem::exists(io::OutputLockPath(out)));  // b still holds it
  b->Release();
  EXPECT_FALSE(std::filesystem::exists(io::OutputLockPath(out)));
}

TEST(FileLock, WaitsForABusyLockUpToItsLimit) {
  test::TempDir dir;
  const std::string out = dir.File("out.ltm");
  Holder h = Holder::Start(out, false, false);
  io::LockOptions o;
  o.wait_seconds = 0.3;
  o.busy_message = [](const std::string& holder) { return "busy: " + holder; };
  auto l = io::FileLock::Acquire(io::OutputLockPath(out), o);
  ASSERT_FALSE(l.ok());
  EXPECT_EQ(l.status().message(), "busy: PID " + std::to_string(h.pid));
  h.Finish();
}

TEST(FileLock, LockFileThatIsAFifoIsRefusedWithoutBlocking) {
  test::TempDir dir;
  const std::string out = dir.File("out.ltm");
  ASSERT_EQ(::mkfifo(io::OutputLockPath(out).c_str(), 0644), 0);
  auto l = io::LockOutput(out);
  ASSERT_FALSE(l.ok());
  EXPECT_TRUE(Contains(l.status().message(), "is a FIFO")) << l.status().message();
}

TEST(ContainerWriter, SecondWriterTouchesNothing) {
  test::TempDir dir;
  const std::string out = dir.File("out.ltm");
  Holder h = Holder::Start(out, true, false);
  const std::vector<char> before = test::ReadFileBytes(out);
  ASSERT_FALSE(before.empty());
  struct stat st0;
  ASSERT_EQ(::stat(out.c_str(), &st0), 0);
  for (bool overwrite : {false, true}) {
    io::WriterOptions wo;
    wo.overwrite_mismatch = overwrite;
    // Other metadata: without the lock this would replace the file (overwrite) or be refused.
    auto w = io::ContainerWriter::Open(out, test::MatrixMetadata(16, 4, format::Layout::kRows, 4), wo);
    ASSERT_FALSE(w.ok());
    EXPECT_EQ(w.status().code(), StatusCode::kFailedPrecondition);
    EXPECT_TRUE(Contains(w.status().message(), out + " is in use by PID " + std::to_string(h.pid)))
        << w.status().message();
  }
  struct stat st1;
  ASSERT_EQ(::stat(out.c_str(), &st1), 0);
  EXPECT_EQ(st0.st_ino, st1.st_ino);
  EXPECT_EQ(test::ReadFileBytes(out), before);
  h.Finish();
  auto w = io::ContainerWriter::Open(out, test::MatrixMetadata(8, 4, format::Layout::kRows, 4));
  ASSERT_TRUE(w.ok()) << w.status().message();
  EXPECT_TRUE(w->resume_info().resumed);
}

}  // namespace
}  // namespace ltb
