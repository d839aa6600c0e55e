// The command line as a user meets it: help texts, and one clear line plus a non-zero exit for
// every bad command line or missing input.

#include "tests/pipeline/cli_runner.h"

#include <gtest/gtest.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <sys/wait.h>

namespace fs = std::filesystem;

namespace {

using Result = flyover::test::CliResult;
using flyover::test::lineCount;
using flyover::test::runFlyover;

} // namespace

TEST(Cli, HelpDescribesEverySubcommand)
{
    const Result top = runFlyover("--help");
    EXPECT_EQ(top.exitCode, 0) << top.err;
    for (const char* sub : {"phantom", "run", "params"})
        EXPECT_NE(top.out.find(sub), std::string::npos) << "top-level help lacks " << sub;

    const Result phantom = runFlyover("phantom --help");
    EXPECT_EQ(phantom.exitCode, 0);
    for (const char* opt : {"--truth", "--truth-mask", "--size", "--seed", "small", "--stricture", "--collapse"})
        EXPECT_NE(phantom.out.find(opt), std::string::npos) << "phantom help lacks " << opt;

    const Result run = runFlyover("run --help");
    EXPECT_EQ(run.exitCode, 0);
    for (const char* opt : {"--study", "--set", "--config", "--until"})
        EXPECT_NE(run.out.find(opt), std::string::npos) << "run help lacks " << opt;

    const Result params = runFlyover("params");
    EXPECT_EQ(params.exitCode, 0);
    EXPECT_NE(params.out.find("segment.air_threshold_hu = -800"), std::string::npos) << params.out;
}

TEST(Cli, MissingInputFileGivesOneLineAndNonZeroExit)
{
    const fs::path study = fs::temp_directory_path() / ("flyover-cli-study-" + std::to_string(::getpid()));
    const Result r = runFlyover("run /nonexistent/scan.nii.gz --study " + study.string());
    EXPECT_NE(r.exitCode, 0);
    EXPECT_EQ(lineCount(r.err), 1) << r.err;
    EXPECT_NE(r.err.find("/nonexistent/scan.nii.gz"), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(study / "manifest.json"));
    fs::remove_all(study);
}

TEST(Cli, BadCommandLinesGiveOneLineAndNonZeroExit)
{
    for (const char* args : {"", "frobnicate", "run", "run a.nii.gz", "phantom out.nii.gz",
                             "phantom out.nii.gz --truth t.json --size huge",
                             "run a.nii.gz --study s --set segment.nope=1",
                             "run a.nii.gz --study s --set render.fov_deg=abc", "--threads -2 params",
                             "phantom out.nii --truth t.json --part --stricture",
                             "phantom out.nii --truth t.json --part --touching 2"}) {
        const Result r = runFlyover(args);
        EXPECT_NE(r.exitCode, 0) << "flyover " << args;
        EXPECT_EQ(lineCount(r.err), 1) << "flyover " << args << "\nstderr: " << r.err;
        EXPECT_NE(r.err.find("error"), std::string::npos) << "flyover " << args << "\nstderr: " << r.err;
    }
    const Result r = runFlyover("run a.nii.gz --study s --set segment.nope=1");
    EXPECT_NE(r.err.find("segment.nope"), std::string::npos) << r.err;
    const Result part = runFlyover("phantom out.nii --truth t.json --part --stricture");
    EXPECT_NE(part.err.find("--stricture"), std::string::npos) << part.err;
    EXPECT_FALSE(fs::exists("out.nii")) << "a refused phantom wrote its file";
}

TEST(Cli, CorruptInputNamesTheFile)
{
    const fs::path dir = fs::temp_directory_path() / ("flyover-cli-corrupt-" + std::to_string(::getpid()));
    fs::create_directories(dir);
    std::ofstream(dir / "broken.nii.gz") << "this is not a NIfTI file";
    const Result r = runFlyover("--quiet run " + (dir / "broken.nii.gz").string() + " --study " + (dir / "study").string());
    EXPECT_NE(r.exitCode, 0);
    EXPECT_EQ(lineCount(r.err), 1) << r.err;
    EXPECT_NE(r.err.find("broken.nii.gz"), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("ingest"), std::string::npos) << "the failing stage is named\n" << r.err;
    EXPECT_FALSE(fs::exists(dir / "study" / "ct.vdb"));
    fs::remove_all(dir);
}

TEST(Cli, TomlConfigIsReadAndUnknownKeysAreRejectedByName)
{
    const fs::path dir = fs::temp_directory_path() / ("flyover-cli-toml-" + std::to_string(::getpid()));
    fs::create_directories(dir);
    std::ofstream(dir / "bad.toml") << "[render]\nfov_deg = 60\nroll_degrees = 10\n";
    std::ofstream(dir / "scan.nii.gz") << "x";
    Result r = runFlyover("-q run " + (dir / "scan.nii.gz").string() + " --study " + (dir / "s").string() +
                          " --config " + (dir / "bad.toml").string());
    EXPECT_EQ(r.exitCode, 2) << r.err;
    EXPECT_NE(r.err.find("render.roll_degrees"), std::string::npos) << r.err;
    EXPECT_EQ(lineCount(r.err), 1) << r.err;

    std::ofstream(dir / "broken.toml") << "[render\nfov_deg = ";
    r = runFlyover("-q run " + (dir / "scan.nii.gz").string() + " --study " + (dir / "s").string() +
                   " --config " + (dir / "broken.toml").string());
    EXPECT_NE(r.exitCode, 0);
    EXPECT_NE(r.err.find("broken.toml"), std::string::npos) << r.err;
    EXPECT_EQ(lineCount(r.err), 1) << r.err;

    std::ofstream(dir / "bad.json") << "{\"segment\": {\"air_threshold\": -700}}";
    r = runFlyover("-q run " + (dir / "scan.nii.gz").string() + " --study " + (dir / "s").string() +
                   " --config " + (dir / "bad.json").string());
    EXPECT_EQ(r.exitCode, 2) << r.err;
    EXPECT_NE(r.err.find("segment.air_threshold"), std::string::npos) << r.err;
    fs::remove_all(dir);
}

TEST(Cli, StatusAndCleanOnAStudy)
{
    const fs::path dir = fs::temp_directory_path() / ("flyover-cli-status-" + std::to_string(::getpid()));
    fs::create_directories(dir);
    Result r = runFlyover("status --study " + (dir / "none").string());
    EXPECT_NE(r.exitCode, 0);
    EXPECT_NE(r.err.find("not a flyover study"), std::string::npos) << r.err;
    EXPECT_EQ(lineCount(r.err), 1) << r.err;
    r = runFlyover("clean --study " + (dir / "none").string());
    EXPECT_NE(r.exitCode, 0);
    EXPECT_EQ(lineCount(r.err), 1) << r.err;
    fs::remove_all(dir);
}

TEST(Cli, GlobalOptionsAreAcceptedAfterTheSubcommand)
{
    // What a newcomer types first: the global options after the subcommand and its arguments.
    const fs::path study = fs::temp_directory_path() / ("flyover-cli-global-" + std::to_string(::getpid()));
    const Result r = runFlyover("run /nonexistent/scan.nii.gz --study " + study.string() + " --log-json --threads 1");
    EXPECT_EQ(r.exitCode, 1) << "expected the missing-file error (exit 1), not a parse error (exit 2): " << r.err;
    EXPECT_EQ(r.err.find("--log-json"), std::string::npos) << "--log-json was refused after 'run': " << r.err;
    EXPECT_NE(r.err.find("/nonexistent/scan.nii.gz"), std::string::npos) << r.err;
    const Result q = runFlyover("params --quiet");
    EXPECT_EQ(q.exitCode, 0) << q.err;
    const Result bad = runFlyover("params --no-such-option");
    EXPECT_EQ(bad.exitCode, 2) << "an unknown option after a subcommand must still be refused: " << bad.err;
    EXPECT_EQ(lineCount(bad.err), 1) << bad.err;
    fs::remove_all(study);
}
