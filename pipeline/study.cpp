#include "pipeline/study.h"

#include "pipeline/artifact_io.h"
#include "pipeline/artifact_store.h"
#include "pipeline/deferred_writes.h"
#include "pipeline/digest_stamps.h"
#include "pipeline/stage_run.h"
#include "volume/error.h"
#include "volume/image.h"

#include <tbb/flow_graph.h>

#include <algorithm>
#include <chrono>
#include <exception>
#include <functional>
#include <filesystem>
#include <map>
#include <mutex>
#include <set>
#include <optional>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

namespace {

/// The render steps; `--until render`, `--force render` and "render" in stagesNeededFor /
/// stagesAffectedBy mean all of them (the stages whose parameter section is "render").
const char* const RENDER_GROUP = "render";

/// Whether a stage reads the scan itself (skipped, "unused", in a study without a CT).
bool readsScan(const StageSpec& spec)
{
    return std::find(spec.inputs.begin(), spec.inputs.end(), "input") != spec.inputs.end();
}

const std::string& paramStageOf(const StageSpec& spec) { return spec.paramStage.empty() ? spec.name : spec.paramStage; }

/// The canonical parameters a stage's key covers.
json stageParams(const StageSpec& spec, const ParamSet& params)
{
    const json all = params.sectionJson(paramStageOf(spec));
    json subset = spec.paramNames.empty() ? all : json::object();
    for (const auto& n : spec.paramNames) subset[n] = all.at(n);
    for (const auto& n : spec.otherParams) {
        const auto dot = n.find('.');
        subset[n] = params.sectionJson(n.substr(0, dot)).at(n.substr(dot + 1));
    }
    return subset;
}

int stageVersionOf(const StageSpec& spec, const ParamSet& params) { return params.sectionVersion(paramStageOf(spec)); }

const StageSpec& specOf(const std::string& name, const StudyPipeline& pipeline)
{
    for (const auto& s : pipeline.stages)
        if (s.name == name) return s;
    std::string known;
    for (const auto& s : pipeline.stages) known += (known.empty() ? "" : ", ") + s.name;
    throw ParameterError("unknown stage '" + name + "' (stages: " + known + ", or " + RENDER_GROUP +
                         " for all render steps)");
}

/// The stages a name stands for: itself, or every render step for "render".
std::vector<std::string> stagesNamed(const std::string& name, const StudyPipeline& pipeline)
{
    std::vector<std::string> out;
    for (const auto& s : pipeline.stages)
        if (s.paramStage == name && name == RENDER_GROUP) out.push_back(s.name);
    if (out.empty()) out.push_back(specOf(name, pipeline).name);
    return out;
}

/// Digest of the scan: its content (a DICOM folder: the names and contents of its files),
/// never its modification time.
std::string inputDigest(const std::string& ctPath) { return artifactDigest(ctPath); }

/// The artifacts a stage reads in a study with or without a CT and a mask: with a mask the
/// stage that takes it also reads the mask ("mask", its content digest), and without a CT only it.
std::vector<std::string> stageInputs(const StageSpec& spec, bool hasCt, bool hasMask)
{
    if (spec.takesMask && hasMask && !hasCt) return {"mask"};
    std::vector<std::string> in = spec.inputs;
    if (spec.takesMask && hasMask) in.push_back("mask");
    if (hasCt) in.insert(in.end(), spec.inputsWithCt.begin(), spec.inputsWithCt.end());
    return in;
}

/// A path recorded in a manifest ("" when absent or null).
std::string recordedPath(const json& manifest, const char* key)
{
    return manifest.is_object() && manifest.contains(key) && manifest[key].is_string() ? manifest[key].get<std::string>()
                                                                                         : std::string();
}

json readManifest(const fs::path& dir)
{
    const fs::path p = dir / "manifest.json";
    if (!fs::exists(p)) return json();
    try {
        return readJson(p.string());
    } catch (const InputError&) {
        return json();
    }
}

json manifestEntry(const json& manifest, const std::string& stage)
{
    if (manifest.is_object() && manifest.contains("stages"))
        for (const auto& e : manifest["stages"])
            if (e.value("stage", "") == stage) return e;
    return json();
}

/// Whether the study's files are the outputs of `record`: "" when they are, else why not
/// (missing, the output of another parameter set of the stage, or modified).
std::string studyFilesProblem(const ArtifactStore& store, const fs::path& dir, const std::string& stage,
                              const json& record)
{
    for (auto it = record.at("outputs").begin(); it != record.at("outputs").end(); ++it) {
        const fs::path p = dir / it.key();
        if (!fs::exists(p)) return it.key() + " is missing from the study (run restores it from the cache)";
        std::string digest;
        try {
            digest = artifactDigest(p.string());
        } catch (const InputError&) {
            return it.key() + " in the study is unreadable (run restores it from the cache)";
        }
        if (digest == it.value().get<std::string>()) continue;
        if (store.anotherRecordHas(stage, it.key(), digest, record.value("key", "")))
            return it.key() + " in the study holds the output of other " + stage +
                   " parameters than these (run restores it from the cache)";
        return it.key() + " in the study is corrupt, incomplete or modified (digest mismatch; run restores it from "
                          "the cache)";
    }
    return {};
}

std::vector<const StudyPipeline*>& registry()
{
    static std::vector<const StudyPipeline*> pipelines;
    return pipelines;
}

std::mutex& registryMutex()
{
    static std::mutex m;
    return m;
}

} // namespace

void registerStudyPipeline(const StudyPipeline& pipeline)
{
    std::lock_guard<std::mutex> lock(registryMutex());
    for (const StudyPipeline* p : registry())
        if (p == &pipeline) return;
    registry().push_back(&pipeline);
}

const std::vector<const StudyPipeline*>& studyPipelines() { return registry(); }

const StudyPipeline& studyPipelineOf(const json& manifest)
{
    const std::string name = manifest.is_object() ? manifest.value("pipeline", "") : "";
    for (const StudyPipeline* p : studyPipelines())
        if (p->manifestName == name) return *p;
    throw InputError("a study of an unknown kind (manifest \"pipeline\": \"" + name + "\")");
}

std::vector<std::string> stagesNeededFor(const StudyPipeline& pipeline, const std::string& stage)
{
    const auto named = stagesNamed(stage, pipeline);
    std::set<std::string> needed(named.begin(), named.end());
    for (auto it = pipeline.stages.rbegin(); it != pipeline.stages.rend(); ++it)
        if (needed.count(it->name))
            for (const auto& u : it->upstream) needed.insert(u);
    std::vector<std::string> out;
    for (const auto& s : pipeline.stages)
        if (needed.count(s.name)) out.push_back(s.name);
    return out;
}

std::vector<std::string> stagesAffectedBy(const StudyPipeline& pipeline, const std::string& stage)
{
    const auto named = stagesNamed(stage, pipeline);
    std::set<std::string> affected(named.begin(), named.end());
    for (const auto& s : pipeline.stages)
        for (const auto& u : s.upstream)
            if (affected.count(u)) affected.insert(s.name);
    std::vector<std::string> out;
    for (const auto& s : pipeline.stages)
        if (affected.count(s.name)) out.push_back(s.name);
    return out;
}

namespace {

/// The stages a run computes or reuses (`wanted`) and recomputes whatever the cache holds
/// (`forced`), after its options are checked; without a CT the stages reading the scan are
/// neither.
struct StageSelection {
    std::set<std::string> wanted, forced;
    bool hasCt = false, hasMask = false;
};

StageSelection selectStages(const StudyPipeline& pipeline, const StudyOptions& options)
{
    StageSelection sel;
    const auto& specs = pipeline.stages;
    if (options.untilStage.empty())
        for (const auto& s : specs) sel.wanted.insert(s.name);
    else
        for (const auto& s : stagesNeededFor(pipeline, options.untilStage)) sel.wanted.insert(s);
    if (!options.forceStage.empty())
        for (const auto& s : stagesAffectedBy(pipeline, options.forceStage)) sel.forced.insert(s);
    if (!(options.cacheMaxGb > 0)) throw ParameterError("--cache-max-gb: must be > 0");

    sel.hasCt = !options.ctPath.empty();
    sel.hasMask = !options.maskPath.empty();
    if (!sel.hasCt && !sel.hasMask) throw ParameterError("run: no input: give a CT scan, --mask FILE, or both");
    if (!sel.hasCt)
        for (const auto& spec : specs) {
            if (!readsScan(spec)) continue;
            if (options.untilStage == spec.name)
                throw ParameterError("--until " + spec.name + ": there is no CT scan to " + spec.name);
            sel.wanted.erase(spec.name);
            sel.forced.erase(spec.name);
        }
    std::error_code ec;
    if (sel.hasCt && !fs::exists(options.ctPath, ec)) throw InputError(options.ctPath + ": no such file or directory");
    if (sel.hasMask && !fs::is_regular_file(options.maskPath, ec))
        throw InputError(options.maskPath + ": --mask: no such file");
    if (sel.hasMask && fs::file_size(options.maskPath, ec) == 0)
        throw InputError(options.maskPath + ": --mask: the file is empty");
    return sel;
}

/// One run of a study's stage graph, under the study's lock: each stage's node reuses the
/// cache's record or runs the body; write-behind stages leave their finishing to a commit node;
/// the manifest is rewritten as stages finish and once at the end.
class StudyRunner {
public:
    StudyRunner(const StudyPipeline& pipeline, StageRun& run, StageSelection sel)
        : mPipeline(pipeline), mRun(run), mOptions(run.options), mSel(std::move(sel)),
          mStamps((fs::path(mOptions.studyDir) / ".flyover" / "stamps.json").string()),
          mStore(mOptions.studyDir, &mStamps), mLog(mOptions.log), mPrevious(readManifest(run.dir))
    {
        mStore.removeStaleTemporaries();
        if (mSel.hasCt) mDigests["input"] = mStamps.digest(mOptions.ctPath);
        if (mSel.hasMask) mDigests["mask"] = mStamps.digest(mOptions.maskPath);
        mRunParameters = json::object();
        for (const auto& section : run.params.sections()) mRunParameters[section] = run.params.sectionJson(section);
    }

    json run();

private:
    json manifestOf(const std::map<std::string, json>& done, bool keepPrevious, bool complete) const;
    void recordFinished(const std::string& name, const json& entry);
    bool reuse(const StageSpec& spec, const std::string& key, json& entry);
    void compute(const StageSpec& spec, const std::string& key, json& entry);
    void execute(const StageSpec& spec);
    void commit(const std::string& name);
    std::exception_ptr runGraph();
    std::exception_ptr commitFailures(std::exception_ptr failure);

    const StudyPipeline& mPipeline;
    StageRun& mRun;
    const StudyOptions& mOptions;
    const StageSelection mSel;
    DigestStamps mStamps;
    ArtifactStore mStore;
    RunLog* mLog;
    const json mPrevious;  ///< the manifest before this run
    json mRunParameters;

    std::mutex mMutex;  ///< guards mDigests, mEntries, mUsedRecords, mCommits, mCommitErrors
    std::map<std::string, std::string> mDigests;
    std::map<std::string, json> mEntries;
    std::set<std::string> mUsedRecords;
    /// Write-behind: the finishing of each such stage (rename, fsync, record), left by its body
    /// for its commit node (or, when the graph failed, for the end of the run).
    std::map<std::string, std::function<void()>> mCommits;
    /// A commit's failure is the stage's (reported after the graph), not the graph's.
    std::map<std::string, std::exception_ptr> mCommitErrors;
    std::mutex mManifestMutex;              ///< guards mFinished and the progress writes
    std::map<std::string, json> mFinished;  ///< stages whose files and record are in place
};

// The manifest: the entries of this run's stages so far, plus earlier entries of stages this
// run does not touch. It is rewritten (atomically) each time a stage's files and cache record
// are in place, with "complete": false, so that a killed run leaves a manifest that names what
// finished; the last write says whether every wanted stage finished.
json StudyRunner::manifestOf(const std::map<std::string, json>& done, bool keepPrevious, bool complete) const
{
    json stages = json::array();
    for (const auto& spec : mPipeline.stages) {
        const auto it = done.find(spec.name);
        if (it != done.end()) stages.push_back(it->second);
        else if (keepPrevious && !mSel.wanted.count(spec.name) && !(readsScan(spec) && !mSel.hasCt)) {
            json e = manifestEntry(mPrevious, spec.name);
            if (!e.is_null()) stages.push_back(e);
        }
    }
    const bool hasCt = mSel.hasCt, hasMask = mSel.hasMask;
    json m{{"schema", "flyover.manifest/1"},
           {"world_frame", WORLD_FRAME},
           {"input", hasCt ? json(fs::absolute(mOptions.ctPath).string()) : json(nullptr)},
           {"input_digest", hasCt ? json(mDigests.at("input")) : json(nullptr)},
           {"mask", hasMask ? json(fs::absolute(mOptions.maskPath).string()) : json(nullptr)},
           {"mask_digest", hasMask ? json(mDigests.at("mask")) : json(nullptr)},
           {"complete", complete},
           {"parameters", mRunParameters},
           {"stages", stages}};
    if (!mPipeline.manifestName.empty()) m["pipeline"] = mPipeline.manifestName;
    return m;
}

// A reused stage is only noted (an unchanged re-run stays a single manifest write); the next
// computed stage's write lists it.
void StudyRunner::recordFinished(const std::string& name, const json& entry)
{
    std::lock_guard<std::mutex> g(mManifestMutex);
    mFinished[name] = entry;
    if (!entry.value("computed", true)) return;
    json m;
    {
        std::lock_guard<std::mutex> g2(mMutex);  // digests
        m = manifestOf(mFinished, true, false);
    }
    writeJson(mRun.path("manifest.json"), m);
}

/// The cache's record of the stage under `key`, put in place when it is sound; false when there
/// is none (or it was dropped as unusable).
bool StudyRunner::reuse(const StageSpec& spec, const std::string& key, json& entry)
{
    std::optional<json> record;
    if (!mSel.forced.count(spec.name)) record = mStore.findRecord(spec.name, key);
    if (!record) return false;
    const auto t0 = std::chrono::steady_clock::now();
    const std::string problem = mStore.verifyRecord(*record);
    if (!problem.empty()) {
        if (mLog) mLog->message(spec.name + ": cached result unusable (" + problem + "); recomputing");
        mStore.dropRecord(spec.name, key);
        return false;
    }
    mStore.materialize(*record);
    mStore.touch(spec.name, key);
    const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    entry["outputs"] = record->at("outputs");
    entry["wall_seconds"] = record->value("wall_seconds", 0.0);
    entry["reuse_seconds"] = secs;
    entry["computed"] = false;
    entry["report"] = record->value("report", json::object());
    {
        std::lock_guard<std::mutex> g(mMutex);
        for (auto it = record->at("outputs").begin(); it != record->at("outputs").end(); ++it)
            mDigests[it.key()] = it.value().get<std::string>();
        mEntries[spec.name] = entry;
        mUsedRecords.insert(ArtifactStore::recordFileName(spec.name, key));
    }
    recordFinished(spec.name, entry);
    if (mLog) mLog->stageFinished(spec.name, false, secs, "");
    return true;
}

/// Runs the stage's body, digests its outputs and commits them (now, or for a write-behind
/// stage in its commit node).
void StudyRunner::compute(const StageSpec& spec, const std::string& key, json& entry)
{
    if (mLog) mLog->stageStarted(spec.name);
    StageProgress progress(mLog, spec.name);
    const auto t0 = std::chrono::steady_clock::now();
    auto deferred = std::make_shared<DeferredWrites>();
    json report;
    try {
        const DeferredWrites::Scope scope(spec.writeBehind ? deferred.get() : nullptr);
        report = spec.body(mRun, &progress);
    } catch (const std::exception& e) {
        // Nested: the cause's type stays visible (out of memory, a full disk: retryable).
        std::throw_with_nested(StageError(spec.name, e.what()));
    }
    const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    json outputs = json::object();
    for (const auto& a : spec.outputs) {
        const std::string pending = deferred->pendingFile(mRun.path(a));
        outputs[a] = artifactDigest(pending.empty() ? mRun.path(a) : pending);
    }
    entry["outputs"] = outputs;
    entry["wall_seconds"] = secs;
    entry["computed"] = true;
    entry["report"] = report;
    json record = entry;
    record.erase("computed");
    auto finish = [this, deferred, record, entry, name = spec.name]() mutable {
        crashPoint(("writebehind:" + name + ":before-finish").c_str());
        // The files under their names, then their fsyncs, what the body left to be made behind
        // (the mesh checks) and the record. A run killed in between leaves renamed files
        // without a record, which the next run recomputes.
        deferred->rename();
        crashPoint(("writebehind:" + name + ":renamed").c_str());
        deferred->sync();
        deferred->completeReport(record["report"]);
        entry["report"] = record["report"];
        {
            std::lock_guard<std::mutex> g(mMutex);
            mEntries[name]["report"] = record["report"];
        }
        crashPoint(("writebehind:" + name + ":report-completed").c_str());
        mStore.commit(record);
        // The file objects' digests were computed from their content above: stamp them.
        for (auto it = record.at("outputs").begin(); it != record.at("outputs").end(); ++it) {
            const std::string obj = mStore.objectPath(it.key(), it.value().get<std::string>());
            std::error_code ec;
            if (fs::is_regular_file(obj, ec)) mStamps.hashed(obj, it.value().get<std::string>());
        }
        crashPoint(("stage:" + name + ":committed").c_str());
        recordFinished(name, entry);
    };
    {
        std::lock_guard<std::mutex> g(mMutex);
        for (auto it = outputs.begin(); it != outputs.end(); ++it) mDigests[it.key()] = it.value().get<std::string>();
        mEntries[spec.name] = entry;
        mUsedRecords.insert(ArtifactStore::recordFileName(spec.name, key));
    }
    if (spec.writeBehind) {
        std::lock_guard<std::mutex> g(mMutex);
        mCommits[spec.name] = std::move(finish);  // run by the stage's commit node
    } else {
        finish();
    }
    if (mLog) mLog->stageFinished(spec.name, true, secs, spec.writeBehind ? "artifacts written behind" : "");
}

void StudyRunner::execute(const StageSpec& spec)
{
    if (!mSel.wanted.count(spec.name)) return;
    std::map<std::string, std::string> inputs;
    {
        std::lock_guard<std::mutex> g(mMutex);
        for (const auto& a : stageInputs(spec, mSel.hasCt, mSel.hasMask)) inputs[a] = mDigests.at(a);
    }
    const json params = stageParams(spec, mRun.params);
    const int version = stageVersionOf(spec, mRun.params);
    const std::string key = stageKey(spec.name, version, params, inputs);
    json entry{{"stage", spec.name}, {"version", version}, {"key", key}, {"parameters", params}, {"inputs", inputs}};
    if (!reuse(spec, key, entry)) compute(spec, key, entry);
}

void StudyRunner::commit(const std::string& name)
{
    std::function<void()> finish;
    {
        std::lock_guard<std::mutex> g(mMutex);
        const auto it = mCommits.find(name);
        if (it == mCommits.end()) return;
        finish = std::move(it->second);
        mCommits.erase(it);
    }
    try {
        finish();
    } catch (...) {
        std::lock_guard<std::mutex> g(mMutex);
        mCommitErrors[name] = std::current_exception();
    }
}

// The stage graph: ingest -> segment -> {centerline, mesh} -> frames -> {flythrough, overviews,
// video, coverage}; beside it the early nodes (earlySpecs), each from a stage's hand-on to the
// stages that take its result, and a commit node after each write-behind stage (and after the
// first pair). Parallel loops run inside the nodes. An exception in a stage's node cancels the
// graph and is rethrown by wait_for_all(); it is returned.
std::exception_ptr StudyRunner::runGraph()
{
    using namespace tbb::flow;
    const auto& specs = mPipeline.stages;
    graph g;
    std::map<std::string, std::unique_ptr<continue_node<continue_msg>>> nodes;
    std::map<std::string, std::unique_ptr<broadcast_node<continue_msg>>> handOns;
    std::map<std::string, std::once_flag> handedOn;
    const std::string commitHandOn = mPipeline.commitsAfter;
    // An early node does its work when a stage it feeds is wanted (else it only passes on).
    auto earlyRuns = [&](const EarlySpec& early) {
        return std::any_of(early.feeds.begin(), early.feeds.end(),
                           [&](const std::string& f) { return mSel.wanted.count(f) > 0; });
    };
    std::map<std::string, int> earlyReaders;
    for (const auto& early : mPipeline.early) {
        earlyReaders[early.reads] += earlyRuns(early) ? 1 : 0;
        handOns[early.reads];
    }
    if (!commitHandOn.empty()) handOns[commitHandOn];
    for (auto& [name, node] : handOns) {
        node = std::make_unique<broadcast_node<continue_msg>>(g);
        handedOn[name];
    }
    // Puts a hand-on into the graph, once (a stage's body, or its node after the body).
    auto handOn = [&](const std::string& what) {
        const auto it = handOns.find(what);
        if (it != handOns.end()) std::call_once(handedOn.at(what), [&] { it->second->try_put(continue_msg()); });
    };
    mRun.setHandOns(handOn, earlyReaders);
    for (const auto& spec : specs)
        nodes[spec.name] = std::make_unique<continue_node<continue_msg>>(
            g,
            [this, &handOn, &handOns, &spec](const continue_msg&) {
                execute(spec);
                for (const auto& h : handOns)
                    if (h.first.rfind(spec.name + ":", 0) == 0) handOn(h.first);
            },
            static_cast<node_priority_t>(spec.priority));
    for (const auto& spec : specs) {
        for (const auto& u : spec.upstream) make_edge(*nodes[u], *nodes[spec.name]);
        for (const auto& u : spec.after) make_edge(*nodes[u], *nodes[spec.name]);
    }
    std::vector<std::unique_ptr<continue_node<continue_msg>>> earlyNodes, commitNodes;
    for (const auto& early : mPipeline.early) {
        earlyNodes.push_back(std::make_unique<continue_node<continue_msg>>(
            g, [this, &early, runs = earlyRuns(early)](const continue_msg&) {
                if (!runs) return;
                try {
                    early.body(mRun, nullptr);
                } catch (...) {
                    // Cancelled, or failed: no result, and the stage it feeds does the work itself.
                }
            }));
        make_edge(*handOns.at(early.reads), *earlyNodes.back());
        for (const auto& f : early.feeds) make_edge(*earlyNodes.back(), *nodes.at(f));
    }
    std::map<std::string, continue_node<continue_msg>*> commitOf;
    for (const auto& spec : specs) {
        if (!spec.writeBehind) continue;
        commitNodes.push_back(std::make_unique<continue_node<continue_msg>>(
            g, [this, name = spec.name](const continue_msg&) { commit(name); }));
        make_edge(*nodes[spec.name], *commitNodes.back());
        if (!commitHandOn.empty()) make_edge(*handOns.at(commitHandOn), *commitNodes.back());
        commitOf[spec.name] = commitNodes.back().get();
    }
    // A stage that reads an artifact of the CT from its file (inputsWithCt) starts after the
    // commit of the write-behind stage that writes it: the file is then in place.
    for (const auto& spec : specs)
        for (const auto& a : spec.inputsWithCt)
            for (const auto& w : specs)
                if (commitOf.count(w.name) && std::find(w.outputs.begin(), w.outputs.end(), a) != w.outputs.end())
                    make_edge(*commitOf.at(w.name), *nodes[spec.name]);

    for (const auto& spec : specs)
        if (spec.upstream.empty() && spec.after.empty()) nodes[spec.name]->try_put(continue_msg());
    try {
        g.wait_for_all();
    } catch (...) {
        return std::current_exception();
    }
    return nullptr;
}

/// After the graph: the commits its failure left (of the stages that finished), and the first
/// commit error as the run's failure when the graph itself did not fail.
std::exception_ptr StudyRunner::commitFailures(std::exception_ptr failure)
{
    for (const auto& spec : mPipeline.stages)
        if (spec.writeBehind) commit(spec.name);
    for (const auto& spec : mPipeline.stages) {
        const auto it = mCommitErrors.find(spec.name);
        if (it == mCommitErrors.end()) continue;
        mEntries.erase(spec.name);
        if (failure) continue;
        try {
            std::rethrow_exception(it->second);
        } catch (const std::exception& e) {
            try {  // nested like a stage body's failure: the cause's type stays visible
                std::throw_with_nested(StageError(spec.name, std::string("writing its artifacts: ") + e.what()));
            } catch (...) {
                failure = std::current_exception();
            }
        }
    }
    return failure;
}

json StudyRunner::run()
{
    const std::exception_ptr failure = commitFailures(runGraph());
    // The manifest: this run's entries, plus earlier entries of stages this run did not touch.
    json manifest;
    {
        std::lock_guard<std::mutex> g(mManifestMutex);
        manifest = failure ? manifestOf(mFinished, false, false) : manifestOf(mEntries, true, true);
    }
    writeJson(mRun.path("manifest.json"), manifest);
    mStamps.save();
    if (failure) std::rethrow_exception(failure);

    const uint64_t freed = mStore.evict(static_cast<uint64_t>(mOptions.cacheMaxGb * 1e9), mUsedRecords);
    if (freed > 0 && mLog)
        mLog->message("cache: evicted " + std::to_string(freed / 1000000) + " MB of least recently used results");
    return manifest;
}

} // namespace

nlohmann::json runStudy(const StudyPipeline& pipeline, StageRun& run)
{
    run.params.validate();
    StageSelection sel = selectStages(pipeline, run.options);
    std::error_code ec;
    fs::create_directories(run.options.studyDir, ec);
    if (ec) throw InputError(run.options.studyDir + ": cannot create the study folder: " + ec.message());
    StudyLock lock(run.options.studyDir, run.options.waitForLock);
    StudyRunner runner(pipeline, run, std::move(sel));
    return runner.run();
}

std::vector<StageStatus> studyStatus(const StudyStatusOptions& options, const StatusParamText& text)
{
    const fs::path dir(options.studyDir);
    const json manifest = readManifest(dir);
    if (!fs::exists(dir / ".flyover"))
        throw InputError(options.studyDir + ": not a flyover study (no .flyover/; run 'flyover run' or 'flyover inspect' first)");
    if (manifest.is_null())
        throw InputError(options.studyDir + ": no stage of this study has finished yet (no manifest.json: its first run "
                                            "was stopped or is still running); run 'flyover run' or 'flyover inspect' again");
    // The study's own stage table and kind of parameters (a part study's are inspect's).
    const StudyPipeline& pipeline = studyPipelineOf(manifest);
    const bool complete = manifest.value("complete", true);
    const std::unique_ptr<ParamSet> paramsOwned = options.params ? options.params->clone() : pipeline.defaultParams();
    ParamSet& params = *paramsOwned;
    const bool given = options.params || !text.assignments.empty() || !text.config.is_null();
    if (given) {
        if (!text.config.is_null()) params.applyJson(text.config, text.configSource);
        for (const auto& a : text.assignments) params.applyAssignment(a);
        params.validate();
    } else {
        // The last run's: its parameters (all sections), then each stage's recorded ones (a stage
        // that the last run did not touch keeps those of the run that made it).
        auto apply = [&](const json& sections) {
            try {
                params.applyJson(sections, "manifest.json");
            } catch (const ParameterError&) {
                // parameters of an older stage version: the stage will show as stale
            }
        };
        if (manifest.contains("parameters") && manifest["parameters"].is_object())
            for (auto it = manifest["parameters"].begin(); it != manifest["parameters"].end(); ++it)
                apply(json{{it.key(), it.value()}});
        for (const auto& spec : pipeline.stages) {
            const json e = manifestEntry(manifest, spec.name);
            if (!e.is_null() && e.contains("parameters")) apply(json{{paramStageOf(spec), e["parameters"]}});
        }
    }
    const std::string ctPath = options.ctPath.empty() ? recordedPath(manifest, "input") : options.ctPath;
    const std::string maskPath = options.maskPath.empty() ? recordedPath(manifest, "mask") : options.maskPath;
    const bool hasCt = !ctPath.empty(), hasMask = !maskPath.empty();
    ArtifactStore store(options.studyDir);

    std::map<std::string, std::string> digests;
    std::vector<StageStatus> out;
    if (hasCt && fs::exists(ctPath)) digests["input"] = inputDigest(ctPath);
    if (hasMask && fs::is_regular_file(maskPath)) digests["mask"] = inputDigest(maskPath);
    for (const auto& spec : pipeline.stages) {
        StageStatus st{spec.name, "", ""};
        if (readsScan(spec) && !hasCt) {
            out.push_back({spec.name, "unused", "no CT scan: the study starts from its mask"});
            continue;
        }
        const json last = manifestEntry(manifest, spec.name);
        std::map<std::string, std::string> inputs;
        std::string missingInput;
        for (const auto& a : stageInputs(spec, hasCt, hasMask)) {
            if (digests.count(a)) inputs[a] = digests[a];
            else if (missingInput.empty()) missingInput = a;
        }
        if (!missingInput.empty()) {
            st.state = last.is_null() ? "missing" : "stale";
            st.reason = missingInput == "input"  ? "the scan " + ctPath + " is missing"
                        : missingInput == "mask" ? "the mask " + maskPath + " is missing"
                                                 : "its input " + missingInput + " will be recomputed";
            out.push_back(st);
            continue;
        }
        const json params2 = stageParams(spec, params);
        const std::string key = stageKey(spec.name, stageVersionOf(spec, params), params2, inputs);
        const auto record = store.findRecord(spec.name, key);
        if (record) {
            std::string problem = store.verifyRecord(*record);
            // The cache holds the result; the study's own files must be that result too, not
            // the output of another parameter set or a modified copy (a run restores them).
            const bool cacheIntact = problem.empty();
            if (cacheIntact)
                problem = studyFilesProblem(store, dir, spec.name, *record);
            if (problem.empty()) {
                st.state = "fresh";
            } else {
                st.state = "stale";
                st.reason = problem;
            }
            if (cacheIntact)
                for (auto it = record->at("outputs").begin(); it != record->at("outputs").end(); ++it)
                    digests[it.key()] = it.value().get<std::string>();
            out.push_back(st);
            continue;
        }
        if (last.is_null()) {
            st.state = "missing";
            st.reason = complete ? "never run" : "not finished by the last run (stopped, failed, or still running)";
        } else {
            st.state = "stale";
            if (last.value("version", -1) != stageVersionOf(spec, params)) st.reason = "stage version changed";
            else if (last["parameters"] != params2) {
                std::string changed;
                for (auto it = params2.begin(); it != params2.end(); ++it)
                    if (!last["parameters"].contains(it.key()) || last["parameters"][it.key()] != it.value())
                        changed += (changed.empty() ? "" : ", ") + paramStageOf(spec) + "." + it.key();
                st.reason = "parameters changed (" + changed + ")";
            } else if (last["inputs"] != json(inputs)) {
                std::string changed;
                for (const auto& [name, d] : inputs)
                    if (!last["inputs"].contains(name) || last["inputs"][name] != d)
                        changed += (changed.empty() ? "" : ", ") + name;
                st.reason = "input changed (" + changed + ")";
            } else {
                st.reason = "its cached result is gone (evicted or removed)";
            }
        }
        out.push_back(st);
    }
    return out;
}

std::vector<std::string> studyReviewNotes(const json& manifest)
{
    std::vector<std::string> notes;
    if (!manifest.is_object() || !manifest.contains("stages") || !manifest["stages"].is_array()) return notes;
    for (const auto& e : manifest["stages"]) {
        if (!e.is_object() || !e.contains("report") || !e["report"].is_object()) continue;
        const json& r = e["report"];
        if (!r.contains("needs_review") || !r["needs_review"].is_array()) continue;
        for (const auto& why : r["needs_review"])
            if (why.is_string()) notes.push_back(e.value("stage", "?") + ": " + why.get<std::string>());
    }
    return notes;
}

std::vector<std::string> studyReviewNotes(const std::string& studyDir) { return studyReviewNotes(readManifest(studyDir)); }

void copyStudy(const std::string& from, const std::string& to)
{
    const fs::path src(from), dst(to);
    if (!fs::exists(src / ".flyover") || !fs::exists(src / "manifest.json"))
        throw InputError(from + ": not a flyover study (no manifest.json or .flyover/)");
    std::error_code ec;
    if (fs::exists(dst, ec)) throw InputError(to + ": already exists (the copy of a study needs a new folder)");
    fs::create_directories(dst / ".flyover");
    for (const auto& e : fs::directory_iterator(src)) {
        const std::string name = e.path().filename().string();
        if (name == ".flyover" || name.rfind(".tmp-", 0) == 0) continue;
        fs::copy(e.path(), dst / name, fs::copy_options::recursive);
    }
    fs::copy(src / ".flyover" / "records", dst / ".flyover" / "records", fs::copy_options::recursive);
    fs::copy(src / ".flyover" / "objects", dst / ".flyover" / "objects",
             fs::copy_options::recursive | fs::copy_options::create_hard_links);
}

void cleanStudy(const std::string& studyDir)
{
    const fs::path dir(studyDir);
    if (!fs::exists(dir / ".flyover") && !fs::exists(dir / "manifest.json"))
        throw InputError(studyDir + ": not a flyover study (no manifest.json or .flyover/)");
    StudyLock lock(studyDir, false);
    std::error_code ec;
    for (const StudyPipeline* pipeline : studyPipelines())
        for (const auto& spec : pipeline->stages)
            for (const auto& a : spec.outputs) fs::remove_all(dir / a, ec);
    fs::remove(dir / "manifest.json", ec);
    for (const auto& e : fs::directory_iterator(dir / ".flyover", ec))
        if (e.path().filename() != "lock") fs::remove_all(e.path(), ec);
    for (const auto& e : fs::directory_iterator(dir, ec))
        if (e.path().filename().string().rfind(".tmp-", 0) == 0) fs::remove_all(e.path(), ec);
}

} // namespace flyover
