// RunChild's way out of a child that will not stop: a forwarded signal it ignores is
// followed by SIGKILL after kill_after_seconds, and deadline_seconds kills it in any case.
// (`sh -c 'trap "" TERM; exec sleep 1000'`: the ignored SIGTERM survives the exec.)
#include "pipeline/process.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <csignal>
#include <string>
#include <string_view>

namespace ltb::pipeline {
namespace {

// How `sh -c script` ended under `io` (its log in the test's temporary directory).
int TermSignal(const std::string& script, ChildIo io) {
  io.log_path = ::testing::TempDir() + "/ltb_process_test_" + std::to_string(::getpid()) + ".log";
  auto r = RunChild({"/bin/sh", "-c", script}, io);
  EXPECT_TRUE(r.ok()) << r.status().message();
  return r.ok() ? r->term_signal : -1;
}

TEST(RunChild, AnIgnoredForwardedSignalIsFollowedBySigkill) {
  ChildIo io;
  bool ready = false;  // signal once the trap is set (the child says so), not before
  io.on_stdout = [&](std::string_view t) { ready = ready || t.find("ready") != std::string_view::npos; };
  io.pending_signal = [&] { return ready ? SIGTERM : 0; };
  io.kill_after_seconds = 0.2;
  EXPECT_EQ(TermSignal("trap '' TERM; echo ready; exec sleep 1000", io), SIGKILL);
}

TEST(RunChild, ADeadlineKillsAChildThatRunsOn) {
  ChildIo io;
  io.deadline_seconds = 0.2;
  EXPECT_EQ(TermSignal("exec sleep 1000", io), SIGKILL);
}

TEST(RunChild, AChildThatStopsOnTheSignalIsNotKilled) {
  ChildIo io;
  io.pending_signal = [] { return SIGTERM; };
  EXPECT_EQ(TermSignal("exec sleep 1000", io), SIGTERM);
}

}  // namespace
}  // namespace ltb::pipeline
