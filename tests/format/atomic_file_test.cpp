// io::AtomicFile: PATH holds its old content or all of the new one, never part of it, and no
// temporary file outlives a writer that returns (committed or not).
#include "format/io/atomic_file.h"

#include <gtest/gtest.h>
#include <sys/stat.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "format/io/file_lock.h"
#include "test_util.h"

namespace ltb {
namespace {

namespace fs = std::filesystem;

std::string ReadAll(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void WriteText(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << text;
}

TEST(AtomicFile, CommitReplacesTheWholeFileAndLeavesNoTemporary) {
  test::TempDir dir;
  const std::string path = dir.File("out.json");
  WriteText(path, "old content, longer than the new one");
  auto f = io::AtomicFile::Create(path);
  ASSERT_TRUE(f.ok()) << f.status().message();
  EXPECT_EQ(f->temp_path(), path + ".partial");
  ASSERT_TRUE(f->file().WriteAt(0, format::ByteSpan(reinterpret_cast<const std::byte*>("new"), 3)).ok());
  // Before Commit the old file is untouched.
  EXPECT_EQ(ReadAll(path), "old content, longer than the new one");
  ASSERT_TRUE(f->Commit().ok());
  EXPECT_EQ(ReadAll(path), "new");
  EXPECT_FALSE(fs::exists(path + ".partial"));
  // A second commit is an error, not a second rename.
  EXPECT_EQ(f->Commit().code(), StatusCode::kFailedPrecondition);
}

TEST(AtomicFile, AWriterThatReturnsWithoutCommitLeavesTheOldFile) {
  test::TempDir dir;
  const std::string path = dir.File("out.npy");
  WriteText(path, "committed");
  {
    auto f = io::AtomicFile::Create(path);
    ASSERT_TRUE(f.ok());
    ASSERT_TRUE(f->file().WriteAt(0, format::ByteSpan(reinterpret_cast<const std::byte*>("half"), 4)).ok());
    EXPECT_TRUE(fs::exists(path + ".partial"));
  }  // an error path: no Commit
  EXPECT_EQ(ReadAll(path), "committed");
  EXPECT_FALSE(fs::exists(path + ".partial"));
  // Nor does a missing file appear.
  const std::string absent = dir.File("never.npy");
  { auto f = io::AtomicFile::Create(absent); }
  EXPECT_FALSE(fs::exists(absent));
  EXPECT_FALSE(fs::exists(absent + ".partial"));
}

TEST(AtomicFile, AStalePartialFileFromAKilledWriterIsReplaced) {
  test::TempDir dir;
  const std::string path = dir.File("cube.npy");
  WriteText(path + ".partial", "left by a writer that was killed");
  ASSERT_TRUE(io::WriteFileAtomically(path, std::string("whole")).ok());
  EXPECT_EQ(ReadAll(path), "whole");
  EXPECT_FALSE(fs::exists(path + ".partial"));
}

TEST(AtomicFile, ALibraryMayWriteTheTemporaryPathItself) {
  // As the EXR and PNG writers do: they open temp_path() on their own (truncating it).
  test::TempDir dir;
  const std::string path = dir.File("image.png");
  auto f = io::AtomicFile::Create(path);
  ASSERT_TRUE(f.ok());
  WriteText(f->temp_path(), "written by another library");
  ASSERT_TRUE(f->Commit().ok());
  EXPECT_EQ(ReadAll(path), "written by another library");
}

TEST(AtomicFile, ErrorsNameThePath) {
  test::TempDir dir;
  const std::string path = dir.File("no-such-dir/out.json");
  auto f = io::AtomicFile::Create(path);
  ASSERT_FALSE(f.ok());
  EXPECT_NE(f.status().message().find(path + ".partial"), std::string::npos) << f.status().message();
  // A directory where the output goes: the rename fails, and the temporary file goes.
  const std::string taken = dir.File("taken");
  ASSERT_TRUE(fs::create_directory(taken));
  ASSERT_TRUE(fs::create_directory(taken + "/inside"));  // a non-empty directory cannot be replaced
  Status s = io::WriteFileAtomically(taken, std::string("x"));
  EXPECT_FALSE(s.ok());
  EXPECT_NE(s.message().find(taken), std::string::npos) << s.message();
  EXPECT_FALSE(fs::exists(taken + ".partial"));
  EXPECT_TRUE(fs::is_directory(taken + "/inside"));
}

// Outputs never replace what is not a regular file: a device, FIFO or directory at the path is
// refused before anything is written (no temporary, no lock file beside it), and stays what it
// was. Before this check `relight --csv /dev/full` turned the device into a regular file.
TEST(AtomicFile, RefusesToReplaceADeviceAFifoOrADirectory) {
  test::TempDir dir;
  const std::string fifo = dir.File("pipe.csv");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0644), 0);
  const std::string empty_dir = dir.File("empty");
  ASSERT_TRUE(fs::create_directory(empty_dir));
  const std::string device_link = dir.File("null.npy");
  fs::create_symlink("/dev/null", device_link);
  struct Case {
    std::string path, kind;
  };
  for (const Case& c : {Case{fifo, "a FIFO"}, Case{empty_dir, "a directory"}, Case{"/dev/null", "a character device"},
                        Case{device_link, "/dev/null, which is a character device"}}) {
    auto f = io::AtomicFile::Create(c.path);
    ASSERT_FALSE(f.ok()) << c.path;
    EXPECT_EQ(f.status().code(), StatusCode::kInvalidArgument) << f.status().message();
    EXPECT_NE(f.status().message().find(c.path + ": is "), std::string::npos) << f.status().message();
    EXPECT_NE(f.status().message().find(c.kind), std::string::npos) << f.status().message();
    EXPECT_FALSE(fs::exists(c.path + ".partial")) << c.path;
    auto lock = io::LockOutput(c.path);
    EXPECT_FALSE(lock.ok()) << c.path;
    EXPECT_FALSE(fs::exists(c.path + ".lock")) << c.path;
    EXPECT_EQ(io::WriteFileAtomically(c.path, std::string("x")).code(), StatusCode::kInvalidArgument);
  }
  EXPECT_TRUE(fs::is_fifo(fifo));
  EXPECT_TRUE(fs::is_directory(empty_dir));
  EXPECT_TRUE(fs::is_symlink(device_link));
  EXPECT_TRUE(fs::is_character_file("/dev/null"));
}

// A symbolic link to a regular file is followed: the file it names gets the new content, the
// link stays a link. A link to nothing is refused.
TEST(AtomicFile, FollowsASymbolicLinkToARegularFileAndRefusesADanglingOne) {
  test::TempDir dir;
  const std::string target = dir.File("real.json"), link = dir.File("link.json");
  WriteText(target, "old");
  fs::create_symlink(target, link);
  ASSERT_TRUE(io::WriteFileAtomically(link, std::string("new")).ok());
  EXPECT_TRUE(fs::is_symlink(link));
  EXPECT_EQ(ReadAll(target), "new");
  EXPECT_FALSE(fs::exists(target + ".partial"));
  const std::string dangling = dir.File("dangling.json");
  fs::create_symlink(dir.File("absent.json"), dangling);
  Status s = io::WriteFileAtomically(dangling, std::string("x"));
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument) << s.message();
  EXPECT_NE(s.message().find("does not exist"), std::string::npos) << s.message();
  EXPECT_FALSE(fs::exists(dir.File("absent.json")));
}

// What is at the path is checked again before the rename: a FIFO made there while the data
// was written is not replaced.
TEST(AtomicFile, ChecksThePathAgainBeforeTheRename) {
  test::TempDir dir;
  const std::string path = dir.File("out.csv");
  auto f = io::AtomicFile::Create(path);
  ASSERT_TRUE(f.ok());
  ASSERT_EQ(::mkfifo(path.c_str(), 0644), 0);
  Status s = f->Commit();
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument) << s.message();
  EXPECT_TRUE(fs::is_fifo(path));
  EXPECT_FALSE(fs::exists(path + ".partial"));
}

}  // namespace
}  // namespace ltb
