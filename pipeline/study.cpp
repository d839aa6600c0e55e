#include "pipeline/study.h"

#include "pipeline/artifact_io.h"
#include "pipeline/artifact_store.h"
#include "pipeline/stage_context.h"
#include "volume/error.h"

#include <tbb/flow_graph.h>

#include <chrono>
#include <exception>
#include <filesystem>
#include <map>
#include <mutex>
#include <set>
#include <optional>

namespace fs = std::filesystem;
using nlohmann::json;

namespace flyover {

openvdb::FloatGrid::Ptr StudyRun::sdf()
{
    std::lock_guard<std::mutex> lock(mLoadMutex);
    if (!state.sdf)
        state.sdf = openvdb::gridPtrCast<openvdb::FloatGrid>(readGrid(path("lumen.vdb"), "lumen_sdf"));
    return state.sdf;
}

namespace {

// ------------------------------------------------------------------------- the stage table

struct StageSpec {
    std::string name;
    std::vector<std::string> upstream;  ///< stages whose outputs this stage reads
    std::vector<std::string> inputs;    ///< artifact names read ("input" = the scan)
    std::vector<std::string> outputs;   ///< artifact names written
    json (*body)(StudyRun&, Progress*);
};

/// The segment stage: from the CT's air, or from the external mask when the run has one.
json runSegmentStage(StudyRun& run, Progress* progress)
{
    return run.opt.maskPath.empty() ? runSegment(run, progress)
                                    : runSegmentFromMask(run, run.opt.maskPath, progress);
}

const std::vector<StageSpec>& stageSpecs()
{
    static const std::vector<StageSpec> specs{
        {"ingest", {}, {"input"}, {"ct.vdb"}, runIngest},
        {"segment", {"ingest"}, {"ct.vdb"}, {"lumen.vdb"}, runSegmentStage},
        {"centerline", {"segment"}, {"lumen.vdb"}, {"centerline.json"}, runCenterline},
        {"mesh", {"segment"}, {"lumen.vdb"}, {"surface.ply"}, runMesh},
        {"render", {"centerline", "mesh"}, {"surface.ply", "centerline.json"}, {"overview.png", "frames", "flythrough", "overviews", "coverage"}, runRender},
    };
    return specs;
}

const StageSpec& specOf(const std::string& name)
{
    for (const auto& s : stageSpecs())
        if (s.name == name) return s;
    std::string known;
    for (const auto& s : stageSpecs()) known += (known.empty() ? "" : ", ") + s.name;
    throw ParameterError("unknown stage '" + name + "' (stages: " + known + ")");
}

/// Digest of the scan: its content (a DICOM folder: the names and contents of its files),
/// never its modification time.
std::string inputDigest(const std::string& ctPath) { return artifactDigest(ctPath); }

/// The artifacts a stage reads in a study with or without a CT and a mask: with a mask the
/// segment stage also reads the mask ("mask", its content digest), and without a CT only it.
std::vector<std::string> stageInputs(const StageSpec& spec, bool hasCt, bool hasMask)
{
    if (spec.name != "segment" || !hasMask) return spec.inputs;
    if (!hasCt) return {"mask"};
    std::vector<std::string> in = spec.inputs;
    in.push_back("mask");
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

} // namespace

std::vector<std::string> stagesNeededFor(const std::string& stage)
{
    std::set<std::string> needed{stage};
    for (auto it = stageSpecs().rbegin(); it != stageSpecs().rend(); ++it)
        if (needed.count(it->name))
            for (const auto& u : it->upstream) needed.insert(u);
    std::vector<std::string> out;
    for (const auto& s : stageSpecs())
        if (needed.count(s.name)) out.push_back(s.name);
    return out;
}

std::vector<std::string> stagesAffectedBy(const std::string& stage)
{
    specOf(stage);
    std::set<std::string> affected{stage};
    for (const auto& s : stageSpecs())
        for (const auto& u : s.upstream)
            if (affected.count(u)) affected.insert(s.name);
    std::vector<std::string> out;
    for (const auto& s : stageSpecs())
        if (affected.count(s.name)) out.push_back(s.name);
    return out;
}

nlohmann::json runPipeline(const RunOptions& options)
{
    validateParams(options.params);
    std::set<std::string> wanted, forced;
    if (options.untilStage.empty())
        for (const auto& s : stageSpecs()) wanted.insert(s.name);
    else
        for (const auto& s : stagesNeededFor(specOf(options.untilStage).name)) wanted.insert(s);
    if (!options.forceStage.empty())
        for (const auto& s : stagesAffectedBy(options.forceStage)) forced.insert(s);
    if (!(options.cacheMaxGb > 0)) throw ParameterError("--cache-max-gb: must be > 0");

    const bool hasCt = !options.ctPath.empty(), hasMask = !options.maskPath.empty();
    if (!hasCt && !hasMask) throw ParameterError("run: no input: give a CT scan, --mask FILE, or both");
    if (!hasCt) {
        if (options.untilStage == "ingest") throw ParameterError("--until ingest: there is no CT scan to ingest");
        wanted.erase("ingest");
        forced.erase("ingest");
    }
    std::error_code ec;
    if (hasCt && !fs::exists(options.ctPath, ec)) throw InputError(options.ctPath + ": no such file or directory");
    if (hasMask && !fs::is_regular_file(options.maskPath, ec))
        throw InputError(options.maskPath + ": --mask: no such file");
    fs::create_directories(options.studyDir, ec);
    if (ec) throw InputError(options.studyDir + ": cannot create the study folder: " + ec.message());

    StudyLock lock(options.studyDir, options.waitForLock);
    ArtifactStore store(options.studyDir);
    store.removeStaleTemporaries();
    StudyRun run(options);
    RunLog* log = options.log;

    std::mutex mutex;  // guards digests and entries
    std::map<std::string, std::string> digests;
    if (hasCt) digests["input"] = inputDigest(options.ctPath);
    if (hasMask) digests["mask"] = inputDigest(options.maskPath);
    std::map<std::string, json> entries;
    std::set<std::string> usedRecords;

    auto execute = [&](const StageSpec& spec) {
        if (!wanted.count(spec.name)) return;
        std::map<std::string, std::string> inputs;
        {
            std::lock_guard<std::mutex> g(mutex);
            for (const auto& a : stageInputs(spec, hasCt, hasMask)) inputs[a] = digests.at(a);
        }
        const json params = stageParamsToJson(options.params, spec.name);
        const int version = stageVersion(spec.name);
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
                std::lock_guard<std::mutex> g(mutex);
                for (auto it = record->at("outputs").begin(); it != record->at("outputs").end(); ++it)
                    digests[it.key()] = it.value().get<std::string>();
                entries[spec.name] = entry;
                usedRecords.insert(ArtifactStore::recordFileName(spec.name, key));
                if (log) log->stageFinished(spec.name, false, secs, "");
                return;
            }
            if (log) log->message(spec.name + ": cached result unusable (" + problem + "); recomputing");
            store.dropRecord(spec.name, key);
        }

        if (log) log->stageStarted(spec.name);
        StageProgress progress(log, spec.name);
        const auto t0 = std::chrono::steady_clock::now();
        json report;
        try {
            report = spec.body(run, &progress);
        } catch (const std::exception& e) {
            // Nested: the cause's type stays visible (out of memory, a full disk: retryable).
            std::throw_with_nested(StageError(spec.name, e.what()));
        }
        const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        json outputs = json::object();
        for (const auto& a : spec.outputs) outputs[a] = artifactDigest(run.path(a));
        entry["outputs"] = outputs;
        entry["wall_seconds"] = secs;
        entry["computed"] = true;
        entry["report"] = report;
        json record2 = entry;
        record2.erase("computed");
        store.commit(record2);
        crashPoint(("stage:" + spec.name + ":committed").c_str());
        std::lock_guard<std::mutex> g(mutex);
        for (auto it = outputs.begin(); it != outputs.end(); ++it) digests[it.key()] = it.value().get<std::string>();
        entries[spec.name] = entry;
        usedRecords.insert(ArtifactStore::recordFileName(spec.name, key));
        if (log) log->stageFinished(spec.name, true, secs, "");
    };

    // The stage graph: ingest -> segment -> {centerline, mesh} -> render. The flow graph runs
    // centerline and mesh side by side; parallel loops run inside each stage. An exception in a
    // node cancels the graph and is rethrown by wait_for_all().
    using namespace tbb::flow;
    graph g;
    std::map<std::string, std::unique_ptr<continue_node<continue_msg>>> nodes;
    for (const auto& spec : stageSpecs())
        nodes[spec.name] = std::make_unique<continue_node<continue_msg>>(
            g, [&execute, &spec](const continue_msg&) { execute(spec); });
    for (const auto& spec : stageSpecs())
        for (const auto& u : spec.upstream) make_edge(*nodes[u], *nodes[spec.name]);

    std::exception_ptr failure;
    nodes["ingest"]->try_put(continue_msg());
    try {
        g.wait_for_all();
    } catch (...) {
        failure = std::current_exception();
    }

    // The manifest: this run's entries, plus earlier entries of stages this run did not touch.
    const json previous = readManifest(run.dir);
    json stages = json::array();
    for (const auto& spec : stageSpecs()) {
        if (entries.count(spec.name)) stages.push_back(entries[spec.name]);
        else if (!failure && !wanted.count(spec.name) && !(spec.name == "ingest" && !hasCt)) {
            json e = manifestEntry(previous, spec.name);
            if (!e.is_null()) stages.push_back(e);
        }
    }
    const json manifest{{"schema", "flyover.manifest/1"},
                        {"world_frame", WORLD_FRAME},
                        {"input", hasCt ? json(fs::absolute(options.ctPath).string()) : json(nullptr)},
                        {"input_digest", hasCt ? json(digests["input"]) : json(nullptr)},
                        {"mask", hasMask ? json(fs::absolute(options.maskPath).string()) : json(nullptr)},
                        {"mask_digest", hasMask ? json(digests["mask"]) : json(nullptr)},
                        {"stages", stages}};
    writeJson(run.path("manifest.json"), manifest);
    if (failure) std::rethrow_exception(failure);

    const uint64_t freed = store.evict(static_cast<uint64_t>(options.cacheMaxGb * 1e9), usedRecords);
    if (freed > 0 && log)
        log->message("cache: evicted " + std::to_string(freed / 1000000) + " MB of least recently used results");
    return manifest;
}

std::vector<StageStatus> studyStatus(const StatusOptions& options)
{
    const fs::path dir(options.studyDir);
    const json manifest = readManifest(dir);
    if (!fs::exists(dir / ".flyover") || manifest.is_null())
        throw InputError(options.studyDir + ": not a flyover study (no manifest.json; run 'flyover run' first)");
    PipelineParams params = options.params;
    if (!options.paramsGiven)
        for (const auto& spec : stageSpecs()) {
            const json e = manifestEntry(manifest, spec.name);
            if (!e.is_null() && e.contains("parameters")) {
                try {
                    applyParamsJson(params, json{{spec.name, e["parameters"]}}, "manifest.json");
                } catch (const ParameterError&) {
                    // parameters of an older stage version: the stage will show as stale
                }
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
    for (const auto& spec : stageSpecs()) {
        StageStatus st{spec.name, "", ""};
        if (spec.name == "ingest" && !hasCt) {
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
        const json params2 = stageParamsToJson(params, spec.name);
        const std::string key = stageKey(spec.name, stageVersion(spec.name), params2, inputs);
        const auto record = store.findRecord(spec.name, key);
        if (record) {
            std::string problem = store.verifyRecord(*record);
            if (problem.empty())
                for (auto it = record->at("outputs").begin(); it != record->at("outputs").end(); ++it) {
                    const fs::path p = dir / it.key();
                    if (!fs::exists(p)) { problem = it.key() + " is missing from the study (run restores it from the cache)"; break; }
                    if (artifactDigest(p.string()) != it.value().get<std::string>()) {
                        problem = it.key() + " in the study is corrupt or modified (digest mismatch)";
                        break;
                    }
                }
            if (problem.empty()) {
                st.state = "fresh";
                for (auto it = record->at("outputs").begin(); it != record->at("outputs").end(); ++it)
                    digests[it.key()] = it.value().get<std::string>();
            } else {
                st.state = "stale";
                st.reason = problem;
                if (problem.find("run restores it") != std::string::npos)
                    for (auto it = record->at("outputs").begin(); it != record->at("outputs").end(); ++it)
                        digests[it.key()] = it.value().get<std::string>();
            }
            out.push_back(st);
            continue;
        }
        if (last.is_null()) {
            st.state = "missing";
            st.reason = "never run";
        } else {
            st.state = "stale";
            if (last.value("version", -1) != stageVersion(spec.name)) st.reason = "stage version changed";
            else if (last["parameters"] != params2) {
                std::string changed;
                for (auto it = params2.begin(); it != params2.end(); ++it)
                    if (!last["parameters"].contains(it.key()) || last["parameters"][it.key()] != it.value())
                        changed += (changed.empty() ? "" : ", ") + spec.name + "." + it.key();
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

void cleanStudy(const std::string& studyDir)
{
    const fs::path dir(studyDir);
    if (!fs::exists(dir / ".flyover") && !fs::exists(dir / "manifest.json"))
        throw InputError(studyDir + ": not a flyover study (no manifest.json or .flyover/)");
    StudyLock lock(studyDir, false);
    std::error_code ec;
    for (const auto& spec : stageSpecs())
        for (const auto& a : spec.outputs) fs::remove_all(dir / a, ec);
    fs::remove(dir / "manifest.json", ec);
    for (const auto& e : fs::directory_iterator(dir / ".flyover", ec))
        if (e.path().filename() != "lock") fs::remove_all(e.path(), ec);
    for (const auto& e : fs::directory_iterator(dir, ec))
        if (e.path().filename().string().rfind(".tmp-", 0) == 0) fs::remove_all(e.path(), ec);
}

} // namespace flyover
