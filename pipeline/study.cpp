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

nlohmann::json runStudy(const StudyPipeline& pipeline, StageRun& run)
{
    const StudyOptions& options = run.options;
    const auto& specs = pipeline.stages;
    run.params.validate();
    std::set<std::string> wanted, forced;
    if (options.untilStage.empty())
        for (const auto& s : specs) wanted.insert(s.name);
    else
        for (const auto& s : stagesNeededFor(pipeline, options.untilStage)) wanted.insert(s);
    if (!options.forceStage.empty())
        for (const auto& s : stagesAffectedBy(pipeline, options.forceStage)) forced.insert(s);
    if (!(options.cacheMaxGb > 0)) throw ParameterError("--cache-max-gb: must be > 0");

    const bool hasCt = !options.ctPath.empty(), hasMask = !options.maskPath.empty();
    if (!hasCt && !hasMask) throw ParameterError("run: no input: give a CT scan, --mask FILE, or both");
    if (!hasCt)
        for (const auto& spec : specs) {
            if (!readsScan(spec)) continue;
            if (options.untilStage == spec.name)
                throw ParameterError("--until " + spec.name + ": there is no CT scan to " + spec.name);
            wanted.erase(spec.name);
            forced.erase(spec.name);
        }
    std::error_code ec;
    if (hasCt && !fs::exists(options.ctPath, ec)) throw InputError(options.ctPath + ": no such file or directory");
    if (hasMask && !fs::is_regular_file(options.maskPath, ec))
        throw InputError(options.maskPath + ": --mask: no such file");
    if (hasMask && fs::file_size(options.maskPath, ec) == 0)
        throw InputError(options.maskPath + ": --mask: the file is empty");
    fs::create_directories(options.studyDir, ec);
    if (ec) throw InputError(options.studyDir + ": cannot create the study folder: " + ec.message());

    StudyLock lock(options.studyDir, options.waitForLock);
    DigestStamps stamps((fs::path(options.studyDir) / ".flyover" / "stamps.json").string());
    ArtifactStore store(options.studyDir, &stamps);
    store.removeStaleTemporaries();
    RunLog* log = options.log;

    std::mutex mutex;  // guards digests and entries
    std::map<std::string, std::string> digests;
    if (hasCt) digests["input"] = stamps.digest(options.ctPath);
    if (hasMask) digests["mask"] = stamps.digest(options.maskPath);
    std::map<std::string, json> entries;
    std::set<std::string> usedRecords;

    // The manifest: the entries of this run's stages so far, plus earlier entries of stages this
    // run does not touch. It is rewritten (atomically) each time a stage's files and cache record
    // are in place, with "complete": false, so that a killed run leaves a manifest that names
    // what finished; the last write says whether every wanted stage finished.
    const json previous = readManifest(run.dir);
    json runParameters = json::object();
    for (const auto& section : run.params.sections()) runParameters[section] = run.params.sectionJson(section);
    auto manifestOf = [&](const std::map<std::string, json>& done, bool keepPrevious, bool complete) {
        json stages = json::array();
        for (const auto& spec : specs) {
            const auto it = done.find(spec.name);
            if (it != done.end()) stages.push_back(it->second);
            else if (keepPrevious && !wanted.count(spec.name) && !(readsScan(spec) && !hasCt)) {
                json e = manifestEntry(previous, spec.name);
                if (!e.is_null()) stages.push_back(e);
            }
        }
        json m{{"schema", "flyover.manifest/1"},
               {"world_frame", WORLD_FRAME},
               {"input", hasCt ? json(fs::absolute(options.ctPath).string()) : json(nullptr)},
               {"input_digest", hasCt ? json(digests.at("input")) : json(nullptr)},
               {"mask", hasMask ? json(fs::absolute(options.maskPath).string()) : json(nullptr)},
               {"mask_digest", hasMask ? json(digests.at("mask")) : json(nullptr)},
               {"complete", complete},
               {"parameters", runParameters},
               {"stages", stages}};
        if (!pipeline.manifestName.empty()) m["pipeline"] = pipeline.manifestName;
        return m;
    };
    std::mutex manifestMutex;              // guards finished and the progress writes
    std::map<std::string, json> finished;  // stages whose files and record are in place
    // A reused stage is only noted (an unchanged re-run stays a single manifest write); the next
    // computed stage's write lists it.
    auto recordFinished = [&](const std::string& name, const json& entry) {
        std::lock_guard<std::mutex> g(manifestMutex);
        finished[name] = entry;
        if (!entry.value("computed", true)) return;
        json m;
        {
            std::lock_guard<std::mutex> g2(mutex);  // digests
            m = manifestOf(finished, true, false);
        }
        writeJson(run.path("manifest.json"), m);
    };
    // Write-behind: the finishing of each such stage (rename, fsync, record), left by its body
    // for its commit node (or, when the graph failed, for the end of the run).
    std::map<std::string, std::function<void()>> commits;  // guarded by mutex
    auto execute = [&](const StageSpec& spec) {
        if (!wanted.count(spec.name)) return;
        std::map<std::string, std::string> inputs;
        {
            std::lock_guard<std::mutex> g(mutex);
            for (const auto& a : stageInputs(spec, hasCt, hasMask)) inputs[a] = digests.at(a);
        }
        const json params = stageParams(spec, run.params);
        const int version = stageVersionOf(spec, run.params);
        const std::string key = stageKey(spec.name, version, params, inputs);
        json entry{{"stage", spec.name}, {"version", version}, {"key", key},
                   {"parameters", params}, {"inputs", inputs}};

        std::optional<json> record;
        if (!forced.count(spec.name)) record = store.findRecord(spec.name, key);
        if (record) {
            const auto t0 = std::chrono::steady_clock::now();
            const std::string problem = store.verifyRecord(*record);
            if (problem.empty()) {
                store.materialize(*record);
                store.touch(spec.name, key);
                const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
                entry["outputs"] = record->at("outputs");
                entry["wall_seconds"] = record->value("wall_seconds", 0.0);
                entry["reuse_seconds"] = secs;
                entry["computed"] = false;
                entry["report"] = record->value("report", json::object());
                {
                    std::lock_guard<std::mutex> g(mutex);
                    for (auto it = record->at("outputs").begin(); it != record->at("outputs").end(); ++it)
                        digests[it.key()] = it.value().get<std::string>();
                    entries[spec.name] = entry;
                    usedRecords.insert(ArtifactStore::recordFileName(spec.name, key));
                }
                recordFinished(spec.name, entry);
                if (log) log->stageFinished(spec.name, false, secs, "");
                return;
            }
            if (log) log->message(spec.name + ": cached result unusable (" + problem + "); recomputing");
            store.dropRecord(spec.name, key);
        }

        if (log) log->stageStarted(spec.name);
        StageProgress progress(log, spec.name);
        const auto t0 = std::chrono::steady_clock::now();
        auto deferred = std::make_shared<DeferredWrites>();
        json report;
        try {
            const DeferredWrites::Scope scope(spec.writeBehind ? deferred.get() : nullptr);
            report = spec.body(run, &progress);
        } catch (const std::exception& e) {
            // Nested: the cause's type stays visible (out of memory, a full disk: retryable).
            std::throw_with_nested(StageError(spec.name, e.what()));
        }
        const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        json outputs = json::object();
        for (const auto& a : spec.outputs) {
            const std::string pending = deferred->pendingFile(run.path(a));
            outputs[a] = artifactDigest(pending.empty() ? run.path(a) : pending);
        }
        entry["outputs"] = outputs;
        entry["wall_seconds"] = secs;
        entry["computed"] = true;
        entry["report"] = report;
        json record2 = entry;
        record2.erase("computed");
        auto finish = [&store, &stamps, &recordFinished, &mutex, &entries, deferred, record2, entry,
                       name = spec.name]() mutable {
            crashPoint(("writebehind:" + name + ":before-finish").c_str());
            // The files under their names, then their fsyncs, what the body left to be made
            // behind (the mesh checks) and the record. A run killed in between leaves renamed
            // files without a record, which the next run recomputes.
            deferred->rename();
            crashPoint(("writebehind:" + name + ":renamed").c_str());
            deferred->sync();
            deferred->completeReport(record2["report"]);
            entry["report"] = record2["report"];
            {
                std::lock_guard<std::mutex> g(mutex);
                entries[name]["report"] = record2["report"];
            }
            crashPoint(("writebehind:" + name + ":report-completed").c_str());
            store.commit(record2);
            // The file objects' digests were computed from their content above: stamp them.
            for (auto it = record2.at("outputs").begin(); it != record2.at("outputs").end(); ++it) {
                const std::string obj = store.objectPath(it.key(), it.value().get<std::string>());
                std::error_code ec;
                if (fs::is_regular_file(obj, ec)) stamps.hashed(obj, it.value().get<std::string>());
            }
            crashPoint(("stage:" + name + ":committed").c_str());
            recordFinished(name, entry);
        };
        {
            std::lock_guard<std::mutex> g(mutex);
            for (auto it = outputs.begin(); it != outputs.end(); ++it) digests[it.key()] = it.value().get<std::string>();
            entries[spec.name] = entry;
            usedRecords.insert(ArtifactStore::recordFileName(spec.name, key));
        }
        if (spec.writeBehind) {
            std::lock_guard<std::mutex> g(mutex);
            commits[spec.name] = std::move(finish);  // run by the stage's commit node
        } else {
            finish();
        }
        if (log) log->stageFinished(spec.name, true, secs, spec.writeBehind ? "artifacts written behind" : "");
    };

    // The stage graph: ingest -> segment -> {centerline, mesh} -> frames -> {flythrough,
    // overviews, video, coverage}; beside it the early nodes (earlySpecs), each from a stage's
    // hand-on to the stages that take its result, and a commit node after each write-behind
    // stage (and after the first pair). Parallel loops run inside the nodes. An exception in a
    // stage's node cancels the graph and is rethrown by wait_for_all().
    using namespace tbb::flow;
    graph g;
    std::map<std::string, std::unique_ptr<continue_node<continue_msg>>> nodes;
    std::map<std::string, std::unique_ptr<broadcast_node<continue_msg>>> handOns;
    std::map<std::string, std::once_flag> handedOn;
    const std::string commitHandOn = pipeline.commitsAfter;
    // An early node does its work when a stage it feeds is wanted (else it only passes on).
    auto earlyRuns = [&](const EarlySpec& early) {
        return std::any_of(early.feeds.begin(), early.feeds.end(), [&](const std::string& f) { return wanted.count(f) > 0; });
    };
    std::map<std::string, int> earlyReaders;
    for (const auto& early : pipeline.early) {
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
    run.setHandOns(handOn, earlyReaders);
    for (const auto& spec : specs)
        nodes[spec.name] = std::make_unique<continue_node<continue_msg>>(
            g,
            [&execute, &handOn, &handOns, &spec](const continue_msg&) {
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
    for (const auto& early : pipeline.early) {
        earlyNodes.push_back(std::make_unique<continue_node<continue_msg>>(g, [&run, &early, runs = earlyRuns(early)](const continue_msg&) {
            if (!runs) return;
            try {
                early.body(run, nullptr);
            } catch (...) {
                // Cancelled, or failed: no result, and the stage it feeds does the work itself.
            }
        }));
        make_edge(*handOns.at(early.reads), *earlyNodes.back());
        for (const auto& f : early.feeds) make_edge(*earlyNodes.back(), *nodes.at(f));
    }
    // A commit's failure is the stage's (reported after the graph), not the graph's: the other
    // stages and commits go on.
    std::map<std::string, std::exception_ptr> commitErrors;  // guarded by mutex
    auto commit = [&](const std::string& name) {
        std::function<void()> finish;
        {
            std::lock_guard<std::mutex> g2(mutex);
            const auto it = commits.find(name);
            if (it == commits.end()) return;
            finish = std::move(it->second);
            commits.erase(it);
        }
        try {
            finish();
        } catch (...) {
            std::lock_guard<std::mutex> g2(mutex);
            commitErrors[name] = std::current_exception();
        }
    };
    std::map<std::string, continue_node<continue_msg>*> commitOf;
    for (const auto& spec : specs) {
        if (!spec.writeBehind) continue;
        commitNodes.push_back(std::make_unique<continue_node<continue_msg>>(
            g, [&commit, name = spec.name](const continue_msg&) { commit(name); }));
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

    std::exception_ptr failure;
    for (const auto& spec : specs)
        if (spec.upstream.empty() && spec.after.empty()) nodes[spec.name]->try_put(continue_msg());
    try {
        g.wait_for_all();
    } catch (...) {
        failure = std::current_exception();
    }
    // The graph failed: the commits of the stages that finished, which their nodes did not run.
    for (const auto& spec : specs)
        if (spec.writeBehind) commit(spec.name);
    for (const auto& spec : specs) {
        const auto it = commitErrors.find(spec.name);
        if (it == commitErrors.end()) continue;
        entries.erase(spec.name);
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

    // The manifest: this run's entries, plus earlier entries of stages this run did not touch.
    json manifest;
    {
        std::lock_guard<std::mutex> g(manifestMutex);
        manifest = failure ? manifestOf(finished, false, false) : manifestOf(entries, true, true);
    }
    writeJson(run.path("manifest.json"), manifest);
    stamps.save();
    if (failure) std::rethrow_exception(failure);

    const uint64_t freed = store.evict(static_cast<uint64_t>(options.cacheMaxGb * 1e9), usedRecords);
    if (freed > 0 && log)
        log->message("cache: evicted " + std::to_string(freed / 1000000) + " MB of least recently used results");
    return manifest;
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
