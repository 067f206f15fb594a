// RunChild's way out of a child that will not stop: a forwarded signal it ignores is
// followed by SIGKILL after kill_after_seconds, and deadline_seconds kills it in any case.
// (`sh -c 'trap "" TERM; exec sleep 1000'`: the ignored SIGTERM survives the exec.)
#include <gtest/gtest.h>

#include <unistd.h>

#include <csignal>
#include <string>
#include <string_view>

#include "pipeline/process.h"

namespace ltb::pipeline {
namespace {

std::string LogPath() { return ::testing::TempDir() + "/ltb_process_test_" + std::to_string(::getpid()) + ".log"; }

TEST(RunChild, AnIgnoredForwardedSignalIsFollowedBySigkill) {
  ChildIo io;
  io.log_path = LogPath();
  bool ready = false;  // signal once the trap is set (the child says so), not before
  io.on_stdout = [&](std::string_view t) { ready = ready || t.find("ready") != std::string_view::npos; };
  io.pending_signal = [&] { return ready ? SIGTERM : 0; };
  io.kill_after_seconds = 0.2;
  auto r = RunChild({"/bin/sh", "-c", "trap '' TERM; echo ready; exec sleep 1000"}, io);
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_EQ(r->term_signal, SIGKILL);
}

TEST(RunChild, ADeadlineKillsAChildThatRunsOn) {
  ChildIo io;
  io.log_path = LogPath();
  io.deadline_seconds = 0.2;
  auto r = RunChild({"/bin/sh", "-c", "exec sleep 1000"}, io);
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_EQ(r->term_signal, SIGKILL);
}

TEST(RunChild, AChildThatStopsOnTheSignalIsNotKilled) {
  ChildIo io;
  io.log_path = LogPath();
  io.pending_signal = [] { return SIGTERM; };
  auto r = RunChild({"/bin/sh", "-c", "exec sleep 1000"}, io);
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_EQ(r->term_signal, SIGTERM);
}

}  // namespace
}  // namespace ltb::pipeline
