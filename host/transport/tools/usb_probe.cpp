// `eyesim-usb-probe`: finds the eyesim device on USB, opens it and claims its interface.
// Exit 0 when the device was opened, 1 when it is absent or cannot be opened (one-line reason on stderr).
#include "eyesim/transport/usb.hpp"

#include <CLI/CLI.hpp>

#include <cstdio>
#include <exception>
#include <string>

int main(int argc, char** argv) {
    CLI::App app{"eyesim-usb-probe: find the eyesim tracking device on USB and open its bulk interface"};
    std::string uri = "usb";
    app.add_option("--device", uri, "usb (default ids 1209:0001) or usb://VID:PID in hex")->capture_default_str();
    try {
        app.parse(argc, argv);
    } catch (const CLI::Success& e) {  // --help
        return app.exit(e);
    } catch (const CLI::ParseError& e) {  // usage error: one line, exit 2
        std::fprintf(stderr, "eyesim-usb-probe: error: %s (see --help)\n", e.what());
        return 2;
    }
    try {
        using namespace eyesim::transport;
        const UsbIds ids = parse_usb_uri(uri);
        const auto devices = list_usb_devices(ids);
        for (const auto& d : devices)
            std::printf("found %04x:%04x on bus %u address %u (%s speed)\n", ids.vendor_id, ids.product_id, d.bus,
                        d.address, d.speed.c_str());
        UsbOptions options;
        options.ids = ids;
        auto link = connect_usb(options);
        std::printf("opened %s: interface %u claimed, bulk IN 0x%02x / OUT 0x%02x\n", link->describe().c_str(),
                    kUsbInterface, kUsbEndpointIn, kUsbEndpointOut);
        return 0;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "eyesim-usb-probe: error: %s\n", e.what());
        return 1;
    }
}
