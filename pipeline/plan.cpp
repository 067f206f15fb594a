#include "pipeline/plan.h"

#include <set>

#include "format/json_text.h"

namespace ltb::pipeline {

using nlohmann::json;

const char* ActionName(Action a) {
  switch (a) {
    case Action::kRun:
      return "run";
    case Action::kResume:
      return "resume";
    case Action::kRedo:
      return "redo";
    case Action::kSkip:
      return "skip";
    case Action::kGiven:
      return "given";
  }
  return "?";
}

std::string FileHash::ForRecord() const {
  switch (state_) {
    case State::kKnown:
      return value_;
    case State::kBeingRemade:
      return std::string();
    case State::kOnDisk:
      return "(computed when run)";
  }
  return std::string();
}

json RecordOutput(const json& record) {
  auto it = record.find("output");
  return it != record.end() && it->is_object() ? *it : json::object();
}

std::string ParamDiff(const json& before, const json& now, const std::string& prefix) {
  std::string out;
  if (before.is_object() && now.is_object()) {
    std::set<std::string> keys;
    for (auto it = before.begin(); it != before.end(); ++it) keys.insert(it.key());
    for (auto it = now.begin(); it != now.end(); ++it) keys.insert(it.key());
    for (const auto& k : keys) {
      json b = before.contains(k) ? before[k] : json(nullptr), a = now.contains(k) ? now[k] : json(nullptr);
      if (b == a) continue;
      std::string d = ParamDiff(b, a, prefix + (prefix.empty() ? "" : ".") + k);
      out += (out.empty() ? "" : ", ") + d;
    }
    return out;
  }
  auto show = [](const json& v) { return v.is_null() ? std::string("(default)") : JsonText(v); };
  return prefix + " " + show(before) + " -> " + show(now);
}

namespace {

// "raw.ltm 0123... -> 4567..., ...": the inputs whose hash differs from the record's.
std::string InputDiff(const json& before, const json& inputs) {
  std::string what;
  for (auto it = inputs.begin(); it != inputs.end(); ++it) {
    std::string old = before.contains(it.key()) ? before[it.key()].get<std::string>() : "(none)";
    if (old != it.value().get<std::string>()) {
      what += (what.empty() ? "" : ", ") + it.key() + " " + old + " -> " + it.value().get<std::string>();
    }
  }
  return what;
}

}  // namespace

Decision Decide(const Node& n, const json* record, const json& inputs, const OutputState& out, bool forced,
                const std::string& needed_reason, bool needed) {
  if (forced) return {Action::kRedo, "forced (--force)"};
  for (auto it = inputs.begin(); it != inputs.end(); ++it) {
    if (it.value().get<std::string>().empty()) {
      return {out.exists && record ? Action::kRedo : Action::kRun,
              "its input " + it.key() + " is being remade (skipped if its content comes out the same)"};
    }
  }
  const bool done = record && record->value("status", "") == "done";
  const bool same_params = record && record->contains("params") && (*record)["params"] == n.params;
  const bool same_inputs = record && record->contains("inputs") && (*record)["inputs"] == inputs;
  const Action remake = out.exists ? Action::kRedo : Action::kRun;
  if (record && !same_params) return {remake, "parameters changed: " + ParamDiff((*record)["params"], n.params, "")};
  if (record && !same_inputs) return {remake, "input changed: " + InputDiff((*record)["inputs"], inputs)};
  if (!out.exists) {
    if (done && RecordOutput(*record).value("deleted", false) && !needed) {
      return {Action::kSkip, "up to date (" + n.output + " was not kept)"};
    }
    return {Action::kRun,
            done ? n.output + " is missing" + (needed_reason.empty() ? "" : " and " + needed_reason) : "not made yet"};
  }
  if (!out.problem.empty()) {
    return {record ? Action::kRedo : Action::kRun, n.output + " is unreadable (" + out.problem + ")"};
  }
  if (!out.complete) {
    return {Action::kResume,
            "interrupted: " + std::to_string(out.committed) + " of " + std::to_string(out.total) + " chunks committed"};
  }
  if (!done) {
    return {Action::kRun, n.output +
                              " exists but run.json has no record of it: the stage checks it (a no-op if it was made "
                              "with the same parameters and input)"};
  }
  const std::string recorded = RecordOutput(*record).value("fingerprint", "");
  if (recorded != out.fingerprint) {
    return {Action::kRedo,
            n.output + " changed since it was made (fingerprint " + recorded + " -> " + out.fingerprint + ")"};
  }
  return {Action::kSkip, "up to date"};
}

Plan PlanSteps(const PlanInput& in) {
  const Graph& g = *in.graph;
  Plan plan;
  plan.steps.resize(g.nodes.size());
  // What is on disk does not change while planning: looked at once per step (an image
  // output is hashed to look at it).
  plan.outputs.reserve(g.nodes.size());
  for (const Node& n : g.nodes) plan.outputs.push_back(in.inspect(n));
  for (int round = 0; round <= static_cast<int>(g.nodes.size()); ++round) {
    std::map<std::string, FileHash> hashes = in.hashes;
    for (size_t i = 0; i < g.nodes.size(); ++i) {
      const Node& n = g.nodes[i];
      const OutputState& out = plan.outputs[i];
      auto rec = in.previous->find(n.name);
      if (in.before_from(n)) {
        plan.steps[i] = {Action::kGiven, "before --from " + in.from};
        if (out.complete && rec != in.previous->end() &&
            RecordOutput(rec->second).value("fingerprint", "") == out.fingerprint) {
          hashes[n.output] = FileHash::Known(RecordOutput(rec->second).value("content_hash", ""));
        } else {
          hashes[n.output] = out.complete ? FileHash::OnDisk() : FileHash::BeingRemade();
        }
        continue;
      }
      json inputs = in.inputs_of(n, hashes);
      const json* record = rec != in.previous->end() ? &rec->second : nullptr;
      auto why = plan.needed_by.find(n.name);
      bool needed = why != plan.needed_by.end() || g.wanted.count(n.output) > 0;
      plan.steps[i] =
          Decide(n, record, inputs, out, in.forced(n), why != plan.needed_by.end() ? why->second : "", needed);
      hashes[n.output] = plan.steps[i].runs() ? FileHash::BeingRemade()
                                              : FileHash::Known(RecordOutput(*record).value("content_hash", ""));
    }
    bool changed = false;
    for (size_t i = g.nodes.size(); i-- > 0;) {
      if (!plan.steps[i].runs()) continue;
      for (const auto& f : g.nodes[i].inputs) {
        for (size_t u = 0; u < i; ++u) {
          const Node& up = g.nodes[u];
          if (up.output != f || plan.steps[u].runs() || in.before_from(up) || plan.needed_by.count(up.name)) continue;
          if (plan.outputs[u].complete) continue;
          plan.needed_by[up.name] = g.nodes[i].name + " needs it";
          changed = true;
        }
      }
    }
    if (!changed) break;
  }
  return plan;
}

Status CheckGivenInputs(const Graph& g, const Plan& plan, const PlanInput& in, const std::string& from,
                        const std::function<std::string(const std::string&)>& path_of) {
  for (size_t i = 0; i < g.nodes.size(); ++i) {
    if (!plan.steps[i].runs()) continue;
    for (const auto& f : g.nodes[i].inputs) {
      for (size_t u = 0; u < g.nodes.size(); ++u) {
        if (g.nodes[u].output == f && in.before_from(g.nodes[u]) && !plan.outputs[u].complete) {
          return FailedPrecondition("--from " + from + ": " + g.nodes[i].name + " reads " + path_of(f) +
                                    ", which does not exist or is incomplete (" + g.nodes[u].name +
                                    " makes it); run without --from, or --from " + g.nodes[u].stages.front());
        }
      }
    }
  }
  return Status::Ok();
}

}  // namespace ltb::pipeline
