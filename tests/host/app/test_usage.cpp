// Usage errors, warnings and the device's linger line, through the programs a user runs: a usage error (an
// option value out of range, a malformed device address, no source or two) is one line on stderr and exit 2;
// a device that is not there is exit 1; warnings go to stderr as one `eyesim: warning: …` line each.
#include "../../firmware/child_process.hpp"

#include "eyesim/transport/transport.hpp"

#include "cli_run.hpp"

#include <catch2/catch.hpp>

#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

namespace {

namespace fs = std::filesystem;

using Result = eyesim::test::CliResult;

/// The test's scratch folder, with a three-field recording in `rec/` made once.
const fs::path& scratch() {
    static const eyesim::test::ScratchDir dir("eyesim_test_usage_exit");
    static const bool made = [] {
        const std::string cmd = std::string(EYESIM_EXE) + " synth --scenario static --seconds 0.06 --out " +
                                (dir.path() / "rec").string() + " >/dev/null 2>&1";
        REQUIRE(std::system(cmd.c_str()) == 0);
        return true;
    }();
    (void)made;
    return dir.path();
}

/// Runs `exe args` (shell words) with a time limit; stdout and stderr apart.
Result run(const std::string& exe, const std::string& args) { return eyesim::test::run_cli(scratch(), exe, args, 60); }

std::string rec() { return (scratch() / "rec").string(); }
std::string rig() { return rec() + "/rig.yaml"; }
std::string scene() { return std::string(EYESIM_SOURCE_DIR) + "/scenes/membrane-peel.json"; }

/// `args` fails with `rc`, stderr exactly one line `<prefix>error: …` that contains `says`, stdout empty.
void one_error_line(const std::string& exe, const std::string& prefix, const std::string& args, int rc,
                    const std::string& says) {
    const Result r = run(exe, args);
    INFO(args << "\n  rc " << r.rc << ", stderr: " << r.err << "  stdout: " << r.out);
    CHECK(r.rc == rc);
    CHECK(r.err.rfind(prefix + "error: ", 0) == 0);
    CHECK(std::count(r.err.begin(), r.err.end(), '\n') == 1);
    CHECK(r.err.find(says) != std::string::npos);
    CHECK(r.out.empty());
}

void usage_error(const std::string& args, const std::string& says) {
    one_error_line(EYESIM_EXE, "eyesim: ", args, 2, says);
}

void device_usage_error(const std::string& args, const std::string& says) {
    one_error_line(EYESIM_DEVICE_EXE, "eyesim-device: ", args, 2, says);
}

}  // namespace

TEST_CASE("track: no source, two sources or a malformed device address is a usage error (exit 2)", "[host][usage]") {
    usage_error("track --rig " + rig(), "track: give exactly one of --connect");
    usage_error("track --rig /no/such/rig.yaml", "track: give exactly one of --connect");  // before any file
    usage_error("track --connect tcp://127.0.0.1:1 --capture " + rec() + "/x.bin --rig " + rig(),
                "give exactly one of");
    usage_error("track --connect tcp://127.0.0.1:1 --usb --rig " + rig(), "give exactly one of");
    usage_error("track --connect tcp://127.0.0.1:70000 --rig " + rig(),
                "--connect: tcp://127.0.0.1:70000: port 70000 is out of range 1..65535");
    usage_error("track --connect tcp://127.0.0.1 --rig " + rig(), "--connect: tcp://127.0.0.1: expected tcp://HOST:PORT");
    usage_error("track --connect tcp://127.0.0.1:abc --rig " + rig(), "port 'abc' is not a number");
    usage_error("track --connect tcp://127.0.0.1:0 --rig " + rig(), "port 0 is not a valid destination");
    usage_error("track --connect udp://x:1 --rig " + rig(), "--connect: udp://x:1: unknown transport");
    usage_error("track --connect usb://12:34 --rig " + rig(), "usb://12:34: expected usb://VID:PID");
    usage_error("track --capture " + rec() + "/x.bin --rig " + rig() + " --instruments pick,scalpel",
                "--instruments: unknown instrument \"scalpel\" (known: ");
    usage_error("track --capture " + rec() + "/x.bin --rig " + rig() + " --no-hints", "--no-hints needs --precision");
}

TEST_CASE("a device that is not there is bad input (exit 1), not a usage error", "[host][usage]") {
    // Port 1 on loopback: well formed, nothing listens.
    one_error_line(EYESIM_EXE, "eyesim: ", "track --connect tcp://127.0.0.1:1 --rig " + rig(), 1, "tcp://127.0.0.1:1");
    one_error_line(EYESIM_EXE, "eyesim: ", "sim --scene " + scene() + " --connect tcp://127.0.0.1:1", 1,
                   "tcp://127.0.0.1:1");
}

TEST_CASE("sim and demo: a malformed address or an unknown scenario is a usage error (exit 2)", "[host][usage]") {
    usage_error("sim --scene " + scene() + " --connect tcp://127.0.0.1", "--connect: tcp://127.0.0.1: expected");
    usage_error("sim --scene " + scene() + " --connect udp://x:1", "unknown transport");
    usage_error("sim --scene /no/such/scene.json --connect tcp://127.0.0.1:99999", "out of range 1..65535");
    usage_error("sim --scene " + scene() + " --scenario nope", "--scenario: nope not in");
    usage_error("sim --scene " + scene() + " --scenario static --seed -1", "--seed: Value -1 not a whole number");
    // Precision mode refines on a device's patches: a scenario (or a recording) has none to send.
    usage_error("sim --scene " + scene() + " --scenario static --precision", "--precision refines markers on a device");
    usage_error("sim --scene " + scene() + " --capture /no/such.bin --no-hints", "--no-hints needs --precision");
    const std::string demo = (scratch() / "demo").string();
    usage_error("demo --out " + demo + " --scenario nope", "--scenario: nope not in");
    usage_error("demo --out " + demo + " --seed -5", "--seed: Value -5 not a whole number");
    CHECK_FALSE(fs::exists(demo));  // refused before anything was synthesised
}

TEST_CASE("synth and fpga: values out of range are usage errors (exit 2)", "[host][usage]") {
    const std::string out = (scratch() / "synth_out").string();
    for (const char* s : {"nan", "-1", "0", "1e12", "inf"})
        usage_error(std::string("synth --seconds ") + s + " --out " + out,
                    std::string("--seconds: Value ") + s + " not a finite number in [0.02, 3600]");
    usage_error("synth --noise 1e9 --out " + out, "--noise: Value 1e9 not a finite number in [0, 32]");
    usage_error("synth --noise -0.5 --out " + out, "--noise: Value -0.5 not a finite number in [0, 32]");
    usage_error("synth --noise nan --out " + out, "--noise: Value nan not a finite number");
    usage_error("synth --seed -1 --out " + out, "--seed: Value -1 not a whole number in [0, 18446744073709551615]");
    usage_error("synth --seed 1.5 --out " + out, "--seed:");
    usage_error("synth --exposure-us 30000 --out " + out, "--exposure-us: must be in (0, 20000]");
    CHECK_FALSE(fs::exists(out));  // nothing written

    usage_error("fpga --recording " + rec() + " --cameras 5", "--cameras: '5': not a camera index 0..2");
    usage_error("fpga --recording " + rec() + " --cameras 0,x", "--cameras: 'x': not a camera index 0..2");
    usage_error("fpga --recording " + rec() + " --reg 0x14", "--reg: '0x14': expected ADDRESS=VALUE");
    usage_error("validate --recording " + rec() + " --seed -1", "--seed: Value -1 not a whole number");
    // Occlusion hints belong to the refinement stage.
    usage_error("fpga --recording " + rec() + " --no-hints", "fpga: --no-hints needs --refine");
    usage_error("validate --recording " + rec() + " --no-hints", "validate: --no-hints needs --refine");

    // The bounds themselves are accepted.
    const Result ok = run(EYESIM_EXE, "synth --scenario static --seconds 0.02 --noise 32 --seed 18446744073709551615 "
                                      "--out " + out + " --json");
    INFO(ok.err);
    CHECK(ok.rc == 0);
    CHECK(ok.out.find("\"fields\":1") != std::string::npos);
}

TEST_CASE("eyesim-device: no source or a bad --seconds is a usage error (exit 2)", "[host][usage]") {
    device_usage_error("--port 0", "give exactly one of --recording DIR or --scenario NAME");
    device_usage_error("--scenario static --seconds nan --port 0", "--seconds: Value nan not a finite number");
    device_usage_error("--scenario static --seconds -1 --port 0", "--seconds: Value -1 not a finite number");
    device_usage_error("--scenario nope --port 0", "--scenario: nope not in");
    device_usage_error("--scenario static --seed -1 --port 0", "--seed: Value -1 not a whole number");
}

TEST_CASE("warnings go to stderr as one 'eyesim: warning:' line each, never to stdout", "[host][usage]") {
    const std::string cap = (scratch() / "torn.bin").string();
    Result r = run(EYESIM_EXE, "fpga --recording " + rec() + " --out " + cap);
    REQUIRE(r.rc == 0);
    fs::resize_file(cap, fs::file_size(cap) - 7);  // a torn tail: replayed up to it, with a warning

    for (const char* json : {"", " --json"}) {
        r = run(EYESIM_EXE, "sim --scene " + scene() + " --capture " + cap + " --rig " + rig() + json);
        INFO("sim" << json << "\n  stderr: " << r.err << "  stdout: " << r.out);
        REQUIRE(r.rc == 0);
        CHECK(r.err.rfind("eyesim: warning: " + cap + ": ", 0) == 0);
        CHECK(r.err.find("torn tail") != std::string::npos);
        CHECK(std::count(r.err.begin(), r.err.end(), '\n') == 1);
        CHECK(r.out.find("warning:") == std::string::npos);
        CHECK(r.out.find("\nwarning") == std::string::npos);
    }
    r = run(EYESIM_EXE, "track --capture " + cap + " --rig " + rig());
    INFO("track\n  stderr: " << r.err << "  stdout: " << r.out);
    REQUIRE(r.rc == 0);
    CHECK(r.err.rfind("eyesim: warning: " + cap + ": ", 0) == 0);
    CHECK(r.err.find("torn tail") != std::string::npos);
    CHECK(std::count(r.err.begin(), r.err.end(), '\n') == 1);
    CHECK(r.out.find("warning") == std::string::npos);
}

TEST_CASE("eyesim-device says why it keeps the link open after the last field", "[host][usage]") {
    eyesim::test::ChildProcess device(
        {EYESIM_DEVICE_EXE, "--recording", rec(), "--port", "0", "--linger-ms", "400"});
    REQUIRE(device.started());
    const std::string listening = device.read_line(10000);
    REQUIRE(listening.rfind("listening tcp://", 0) == 0);
    const std::string uri = listening.substr(std::string("listening ").size());
    // The host keeps the link (pings) until the device closes it: after the linger.
    const Result host = run(EYESIM_EXE, "track --connect " + uri + " --rig " + rig() + " --json");
    INFO(host.err);
    CHECK(host.rc == 0);
    REQUIRE(device.wait(10000) == 0);
    const std::string err = device.drain_stderr();
    INFO(err);
    CHECK(err.find("eyesim-device: recording ended; keeping the link open 0.4 s for late commands (--linger-ms)\n") !=
          std::string::npos);
    CHECK(std::count(err.begin(), err.end(), '\n') == 2);  // that line and the summary
}

TEST_CASE("a malformed device address is a UriError, a refused connection a plain TransportError", "[host][usage]") {
    using namespace eyesim::transport;
    CHECK_THROWS_AS(open_transport("tcp://127.0.0.1"), UriError);
    CHECK_THROWS_AS(open_transport("tcp://127.0.0.1:65536"), UriError);
    CHECK_THROWS_AS(open_transport("serial:///dev/ttyS0"), UriError);
    CHECK_THROWS_AS(open_transport("usb://12:34"), UriError);
    CHECK_THROWS_AS(check_transport_uri("tcp://host:"), UriError);
    CHECK_NOTHROW(check_transport_uri("tcp://[::1]:5100"));
    CHECK_NOTHROW(check_transport_uri("usb"));
    CHECK_NOTHROW(check_transport_uri("usb://1209:0001"));
    bool uri_error = true;
    try {
        open_transport("tcp://127.0.0.1:1", 1000);
    } catch (const UriError&) {
        uri_error = true;
    } catch (const TransportError& e) {
        uri_error = false;
        CHECK(std::string(e.what()).rfind("tcp://127.0.0.1:1", 0) == 0);
    }
    CHECK_FALSE(uri_error);
}
