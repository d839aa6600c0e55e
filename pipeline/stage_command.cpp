#include "pipeline/stage_command.h"

#include "pipeline/artifact_io.h"
#include "pipeline/artifact_store.h"
#include "pipeline/study.h"
#include "volume/error.h"

#include <algorithm>
#include <filesystem>
#include <new>
#include <stdexcept>
#include <system_error>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

namespace {

json readIfPresent(const fs::path& p)
{
    std::error_code ec;
    if (!fs::is_regular_file(p, ec)) return json();
    try {
        return readJson(p.string());
    } catch (const InputError&) {
        return json();
    }
}

/// First line of a message (errors are one line; a nested library message may not be).
std::string oneLine(std::string s)
{
    const auto nl = s.find('\n');
    if (nl != std::string::npos) s.resize(nl);
    return s;
}

bool startsWith(const std::string& s, const std::string& prefix) { return s.rfind(prefix, 0) == 0; }

/// Whether the stage (or the first of the steps a name stands for) reads the scan itself.
bool readsScan(const StudyPipeline& pipeline, const std::string& stage)
{
    for (const auto& s : pipeline.stages)
        if (s.name == stage) return std::find(s.inputs.begin(), s.inputs.end(), "input") != s.inputs.end();
    return false;
}

/// Whether the stage takes the run's --mask.
bool takesMaskStage(const StudyPipeline& pipeline, const std::string& stage)
{
    for (const auto& s : pipeline.stages)
        if (s.name == stage) return s.takesMask;
    return false;
}

/// Refuses unless every stage upstream of `stage` is fresh for these inputs and parameters.
void requireFreshUpstream(const StageCommandOptions& o, const std::string& ctPath, const std::string& maskPath,
                          const json& manifest)
{
    // Stages by their parameter-level names only: a stage made of cached steps (render) is
    // run whole, its own steps are not "upstream".
    const std::vector<std::string>& names = o.pipeline->commandStages;
    std::vector<std::string> upstream;
    for (const auto& s : stagesNeededFor(*o.pipeline, o.stage))
        if (s != o.stage && std::find(names.begin(), names.end(), s) != names.end()) upstream.push_back(s);
    if (ctPath.empty())
        upstream.erase(std::remove_if(upstream.begin(), upstream.end(), [&](const std::string& s) { return readsScan(*o.pipeline, s); }),
                       upstream.end());
    if (upstream.empty()) return;

    std::map<std::string, StageStatus> states;
    if (!manifest.is_null()) {
        StudyStatusOptions so;
        so.studyDir = o.studyDir;
        so.ctPath = ctPath;
        so.maskPath = maskPath;
        so.params = o.params.get();
        for (const auto& st : studyStatus(so)) states[st.stage] = st;
    }
    for (const auto& u : upstream) {
        const auto it = states.find(u);
        if (it != states.end()) {
            const StageStatus& st = it->second;
            // Present in the cache but not linked into the study: the run below restores it.
            const bool restorable = st.state == "stale" && st.reason.find("run restores it") != std::string::npos;
            if (st.state == "fresh" || restorable) continue;
        }
        const json receipt = readIfPresent(receiptPath(o.studyDir, u));
        if (receipt.is_object() && receipt.value("status", "") == "failed")
            throw InputError(o.studyDir + ": " + u + " failed earlier on this study: " +
                             receipt.value("error", std::string("(no message)")));
        const std::string why = it == states.end() ? "has not run" : it->second.state + (it->second.reason.empty() ? "" : " (" + it->second.reason + ")");
        const std::string& prefix = o.pipeline->stagePrefix;
        throw StageNotReady(o.studyDir + ": cannot run " + prefix + o.stage + ": " + u + " " + why +
                            "; run 'flyover stage " + prefix + u + "' first, with the same inputs and parameters");
    }
}

} // namespace

void resolveStagePipeline(StageCommandOptions& o)
{
    const StudyPipeline* chosen = nullptr;
    for (const StudyPipeline* p : studyPipelines())
        if (!p->stagePrefix.empty() && startsWith(o.stage, p->stagePrefix)) {
            o.stage.erase(0, p->stagePrefix.size());
            chosen = p;
        }
    if (!chosen) {
        const json manifest = readIfPresent(fs::path(o.studyDir) / "manifest.json");
        const std::string name = manifest.is_object() ? manifest.value("pipeline", "") : "";
        for (const StudyPipeline* p : studyPipelines())
            if (p->manifestName == name) chosen = p;
        if (!chosen) throw InputError(o.studyDir + ": a study of an unknown kind (manifest \"pipeline\": \"" + name + "\")");
    }
    o.pipeline = chosen;
    o.params = chosen->defaultParams();
}

std::string recordedInput(const json& manifest, const char* key)
{
    return manifest.is_object() && manifest.contains(key) && manifest[key].is_string() ? manifest[key].get<std::string>()
                                                                                         : std::string();
}

std::string receiptPath(const std::string& studyDir, const std::string& stage)
{
    return (fs::path(studyDir) / "stages" / (stage + ".json")).string();
}

json runStageCommand(const StageCommandOptions& o)
{
    if (!o.pipeline || !o.params) throw std::logic_error("runStageCommand: call resolveStagePipeline first");
    const StudyPipeline& pipeline = *o.pipeline;
    const std::vector<std::string>& names = pipeline.commandStages;
    if (std::find(names.begin(), names.end(), o.stage) == names.end()) {
        std::string known;
        for (const auto& n : names) known += (known.empty() ? "" : ", ") + n;
        if (pipeline.stagePrefix.empty())
            for (const StudyPipeline* p : studyPipelines())
                if (p != &pipeline)
                    for (const auto& n : p->commandStages) known += ", " + p->stagePrefix + n;
        throw ParameterError("stage: unknown " + (pipeline.stagePrefix.empty() ? std::string() : pipeline.name + " ") +
                             "stage '" + o.stage + "' (stages: " + known + ")");
    }
    o.params->validate();
    const bool takesMask = std::any_of(pipeline.stages.begin(), pipeline.stages.end(), [](const StageSpec& s) { return s.takesMask; });
    if (!takesMask && !o.maskPath.empty())
        throw ParameterError("stage " + o.stage + ": an " + pipeline.name + " stage takes no --mask");
    // A part study's stage on a colon study (or the other way round) would mix two stage graphs.
    {
        const json m = readIfPresent(fs::path(o.studyDir) / "manifest.json");
        if (m.is_object()) {
            const StudyPipeline& own = studyPipelineOf(m);
            if (&own != &pipeline)
                throw InputError(o.studyDir + ": a " + own.studyWord + " study: stage " + o.stage + " is " +
                                 (pipeline.stagePrefix.empty() ? "the " + pipeline.name + "'s" : pipeline.name + "'s"));
        }
    }
    std::error_code ec;
    const bool startsStudy = readsScan(pipeline, o.stage) || (takesMaskStage(pipeline, o.stage) && !o.maskPath.empty());
    if (!fs::is_directory(o.studyDir, ec) && !startsStudy)
        throw StageNotReady(o.studyDir + ": no such study folder; " + pipeline.firstStageHint);
    fs::remove(receiptPath(o.studyDir, o.stage), ec);

    const json manifest = readIfPresent(fs::path(o.studyDir) / "manifest.json");
    const std::string ctPath = o.ctPath.empty() ? recordedInput(manifest, "input") : o.ctPath;
    const std::string maskPath = o.maskPath.empty() ? recordedInput(manifest, "mask") : o.maskPath;
    if (readsScan(pipeline, o.stage) && ctPath.empty())
        throw ParameterError("stage " + o.stage + ": no CT scan: give --ct (the study records none)");
    if (ctPath.empty() && maskPath.empty())
        throw StageNotReady(o.studyDir + ": the study records no scan and no mask; give --ct or --mask");
    requireFreshUpstream(o, ctPath, maskPath, manifest);

    StudyOptions run;
    run.ctPath = ctPath;
    run.maskPath = maskPath;
    run.studyDir = o.studyDir;
    run.untilStage = o.stage;
    run.waitForLock = o.waitForLock;
    run.cacheMaxGb = o.cacheMaxGb;
    run.log = o.log;
    const json result = pipeline.run(run, *o.params);

    // The stage's manifest entry, or the entries of its steps (a stage the manifest records as
    // several cached steps, such as render's frames, overviews, coverage...).
    std::vector<json> entries;
    for (const auto& e : result["stages"])
        if (e.value("stage", "") == o.stage) entries = {e};
    if (entries.empty() && o.stage == names.back())
        for (const auto& e : result["stages"])
            if (std::find(names.begin(), names.end(), e.value("stage", "")) == names.end()) entries.push_back(e);
    if (entries.empty()) throw StageError(o.stage, "the run recorded no result for this stage");
    json keys = json::object(), outputs = json::object();
    bool computed = false;
    double seconds = 0;
    for (const auto& e : entries) {
        keys[e.value("stage", "")] = e.value("key", std::string());
        if (e.contains("outputs") && e["outputs"].is_object())
            for (auto it = e["outputs"].begin(); it != e["outputs"].end(); ++it) outputs[it.key()] = it.value();
        computed = computed || e.value("computed", false);
        seconds += e.value("wall_seconds", 0.0);
    }
    json receipt{{"schema", "flyover.stage/1"},
                 {"stage", o.stage},
                 {"status", "ok"},
                 {"exit_code", 0},
                 {"computed", computed},
                 {"keys", keys},
                 {"outputs", outputs},
                 {"wall_seconds", seconds},
                 {"world_frame", "LPS"}};
    fs::create_directories(fs::path(o.studyDir) / "stages", ec);
    writeJson(receiptPath(o.studyDir, o.stage), receipt);
    return receipt;
}

void writeFailedReceipt(const std::string& studyDir, const std::string& stage, const std::string& error,
                        int exitCode) noexcept
{
    if (exitCode != EXIT_BAD_INPUT && exitCode != EXIT_BAD_PARAMETER) return;
    try {
        // The name as given (inspect:NAME) or as resolved (NAME), of any registered table.
        std::string name = stage;
        bool known = false;
        for (const StudyPipeline* p : studyPipelines()) {
            const bool prefixed = !p->stagePrefix.empty() && startsWith(stage, p->stagePrefix);
            const std::string n = prefixed ? stage.substr(p->stagePrefix.size()) : stage;
            if (std::find(p->commandStages.begin(), p->commandStages.end(), n) == p->commandStages.end()) continue;
            if (prefixed || !known) name = n;
            known = true;
        }
        if (studyDir.empty() || !known) return;
        std::error_code ec;
        fs::create_directories(fs::path(studyDir) / "stages", ec);
        writeJson(receiptPath(studyDir, name), json{{"schema", "flyover.stage/1"},
                                                     {"stage", name},
                                                     {"status", "failed"},
                                                     {"exit_code", exitCode},
                                                     {"error", oneLine(error)},
                                                     {"world_frame", "LPS"}});
    } catch (...) {
        // The exit code still says it failed; a missing receipt fails the workflow's rule.
    }
}

namespace {

/// True when this exception or one it nests says the machine failed, not the input.
bool transientCause(const std::exception_ptr& error)
{
    try {
        std::rethrow_exception(error);
    } catch (const TransientError&) {
        return true;
    } catch (const std::bad_alloc&) {
        return true;
    } catch (const std::system_error& e) {  // std::filesystem::filesystem_error too
        if (e.code().category() == std::generic_category() || e.code().category() == std::system_category())
            if (isTransientErrno(e.code().value())) return true;
        try {
            std::rethrow_if_nested(e);
        } catch (...) {
            return transientCause(std::current_exception());
        }
    } catch (const std::exception& e) {
        try {
            std::rethrow_if_nested(e);
        } catch (...) {
            return transientCause(std::current_exception());
        }
    } catch (...) {
    }
    return false;
}

} // namespace

int exitCodeFor(const std::exception_ptr& error)
{
    if (transientCause(error)) return EXIT_TEMPFAIL;
    try {
        std::rethrow_exception(error);
    } catch (const StudyBusy&) {
        return EXIT_STUDY_BUSY;
    } catch (const StageNotReady&) {
        return EXIT_NOT_READY;
    } catch (const ParameterError&) {
        return EXIT_BAD_PARAMETER;
    } catch (...) {
        return EXIT_BAD_INPUT;
    }
}

} // namespace flyover
