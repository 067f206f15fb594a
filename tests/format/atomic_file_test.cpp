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

}  // namespace
}  // namespace ltb
