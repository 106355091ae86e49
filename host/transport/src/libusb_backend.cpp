// libusb implementation of UsbBackend/BulkDevice: device lookup by id, interface claim, endpoint discovery,
// synchronous bulk transfers, hotplug arrival notifications where the platform has them.
#include "eyesim/transport/usb.hpp"

#include <libusb.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <thread>

namespace eyesim::transport {
namespace {

UsbStatus map_status(int rc) {
    switch (rc) {
        case LIBUSB_SUCCESS: return UsbStatus::ok;
        case LIBUSB_ERROR_TIMEOUT: return UsbStatus::timeout;
        case LIBUSB_ERROR_NO_DEVICE: return UsbStatus::no_device;
        case LIBUSB_ERROR_NOT_FOUND: return UsbStatus::not_found;
        case LIBUSB_ERROR_ACCESS: return UsbStatus::access;
        case LIBUSB_ERROR_BUSY: return UsbStatus::busy;
        case LIBUSB_ERROR_OVERFLOW: return UsbStatus::overflow;
        case LIBUSB_ERROR_PIPE: return UsbStatus::pipe;
        default: return UsbStatus::io;
    }
}

std::string ids_text(const UsbIds& ids) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "usb://%04x:%04x", ids.vendor_id, ids.product_id);
    return buf;
}

const char* speed_name(int s) {
    switch (s) {
        case LIBUSB_SPEED_LOW: return "low";
        case LIBUSB_SPEED_FULL: return "full";
        case LIBUSB_SPEED_HIGH: return "high";
        case LIBUSB_SPEED_SUPER: return "super";
        case LIBUSB_SPEED_SUPER_PLUS: return "super+";
        default: return "unknown";
    }
}

class LibusbDevice final : public BulkDevice {
public:
    LibusbDevice(libusb_device_handle* h, std::uint8_t ep_in, std::uint8_t ep_out, std::uint16_t mps_in,
                 std::uint16_t mps_out)
        : handle_(h), ep_in_(ep_in), ep_out_(ep_out), mps_in_(mps_in), mps_out_(mps_out) {}
    ~LibusbDevice() override {
        libusb_release_interface(handle_, kUsbInterface);
        libusb_close(handle_);
    }
    LibusbDevice(const LibusbDevice&) = delete;
    LibusbDevice& operator=(const LibusbDevice&) = delete;

    UsbStatus bulk_in(std::uint8_t* buf, std::size_t len, std::size_t& transferred, unsigned timeout_ms) override {
        int got = 0;
        const int rc = libusb_bulk_transfer(handle_, ep_in_, buf, static_cast<int>(len), &got, timeout_ms);
        transferred = static_cast<std::size_t>(got);
        return map_status(rc);
    }
    UsbStatus bulk_out(const std::uint8_t* buf, std::size_t len, std::size_t& transferred,
                       unsigned timeout_ms) override {
        int sent = 0;
        static std::uint8_t empty = 0;  // libusb wants a valid pointer even for a zero-length packet
        const int rc = libusb_bulk_transfer(handle_, ep_out_, buf ? const_cast<std::uint8_t*>(buf) : &empty,
                                            static_cast<int>(len), &sent, timeout_ms);
        transferred = static_cast<std::size_t>(sent);
        return map_status(rc);
    }
    std::uint16_t max_packet_in() const override { return mps_in_; }
    std::uint16_t max_packet_out() const override { return mps_out_; }

private:
    libusb_device_handle* handle_;
    std::uint8_t ep_in_, ep_out_;
    std::uint16_t mps_in_, mps_out_;
};

class LibusbBackend final : public UsbBackend {
public:
    explicit LibusbBackend(const UsbIds& ids) {
        if (const int rc = libusb_init(&ctx_); rc != 0)
            throw TransportError(ids_text(ids) + ": cannot initialise libusb: " + libusb_error_name(rc));
        if (libusb_has_capability(LIBUSB_CAP_HAS_HOTPLUG)) {
            const int rc = libusb_hotplug_register_callback(
                ctx_, LIBUSB_HOTPLUG_EVENT_DEVICE_ARRIVED, LIBUSB_HOTPLUG_NO_FLAGS, ids.vendor_id, ids.product_id,
                LIBUSB_HOTPLUG_MATCH_ANY, &LibusbBackend::on_arrival, this, &hotplug_);
            hotplug_ok_ = rc == LIBUSB_SUCCESS;
        }
    }
    ~LibusbBackend() override {
        if (hotplug_ok_) libusb_hotplug_deregister_callback(ctx_, hotplug_);
        libusb_exit(ctx_);
    }
    LibusbBackend(const LibusbBackend&) = delete;
    LibusbBackend& operator=(const LibusbBackend&) = delete;

    UsbStatus open(const UsbIds& ids, std::unique_ptr<BulkDevice>& out, std::string& why) override {
        const std::string name = ids_text(ids);
        libusb_device** list = nullptr;
        const ssize_t n = libusb_get_device_list(ctx_, &list);
        if (n < 0) {
            why = name + ": cannot list USB devices: " + libusb_error_name(static_cast<int>(n));
            return map_status(static_cast<int>(n));
        }
        UsbStatus result = UsbStatus::not_found;
        why = name + ": no device found (is it plugged in and powered? on Linux, does a udev rule grant access?)";
        for (ssize_t i = 0; i < n && !out; ++i) {
            libusb_device_descriptor d{};
            if (libusb_get_device_descriptor(list[i], &d) != 0) continue;
            if (d.idVendor != ids.vendor_id || d.idProduct != ids.product_id) continue;
            result = open_one(list[i], name, out, why);
        }
        libusb_free_device_list(list, 1);
        return out ? UsbStatus::ok : result;
    }

    bool hotplug_supported() const override { return hotplug_ok_; }

    bool wait_for_arrival(int timeout_ms) override {
        if (!hotplug_ok_) {
            std::this_thread::sleep_for(std::chrono::milliseconds(std::max(timeout_ms, 0)));
            return false;
        }
        timeval tv{timeout_ms / 1000, (timeout_ms % 1000) * 1000};
        libusb_handle_events_timeout_completed(ctx_, &tv, nullptr);
        return arrived_.exchange(false);
    }

    std::vector<UsbDeviceInfo> list(const UsbIds& ids) {
        std::vector<UsbDeviceInfo> found;
        libusb_device** list = nullptr;
        const ssize_t n = libusb_get_device_list(ctx_, &list);
        if (n < 0) throw TransportError(ids_text(ids) + ": cannot list USB devices: " +
                                        libusb_error_name(static_cast<int>(n)));
        for (ssize_t i = 0; i < n; ++i) {
            libusb_device_descriptor d{};
            if (libusb_get_device_descriptor(list[i], &d) != 0) continue;
            if (d.idVendor != ids.vendor_id || d.idProduct != ids.product_id) continue;
            found.push_back({libusb_get_bus_number(list[i]), libusb_get_device_address(list[i]),
                             speed_name(libusb_get_device_speed(list[i]))});
        }
        libusb_free_device_list(list, 1);
        return found;
    }

private:
    static int LIBUSB_CALL on_arrival(libusb_context*, libusb_device*, libusb_hotplug_event, void* self) {
        static_cast<LibusbBackend*>(self)->arrived_ = true;
        return 0;  // stay registered
    }

    UsbStatus open_one(libusb_device* dev, const std::string& name, std::unique_ptr<BulkDevice>& out,
                       std::string& why) {
        // Find the bulk endpoints of the eyesim interface in the active configuration.
        libusb_config_descriptor* cfg = nullptr;
        if (const int rc = libusb_get_active_config_descriptor(dev, &cfg); rc != 0) {
            why = name + ": cannot read configuration descriptor: " + libusb_error_name(rc);
            return map_status(rc);
        }
        std::uint8_t ep_in = 0, ep_out = 0;
        std::uint16_t mps_in = 0, mps_out = 0;
        for (int i = 0; i < cfg->bNumInterfaces; ++i) {
            const libusb_interface& itf = cfg->interface[i];
            for (int a = 0; a < itf.num_altsetting; ++a) {
                const libusb_interface_descriptor& alt = itf.altsetting[a];
                if (alt.bInterfaceNumber != kUsbInterface || alt.bAlternateSetting != 0) continue;
                for (int e = 0; e < alt.bNumEndpoints; ++e) {
                    const libusb_endpoint_descriptor& ep = alt.endpoint[e];
                    if ((ep.bmAttributes & LIBUSB_TRANSFER_TYPE_MASK) != LIBUSB_TRANSFER_TYPE_BULK) continue;
                    if (ep.bEndpointAddress & LIBUSB_ENDPOINT_IN) {
                        ep_in = ep.bEndpointAddress;
                        mps_in = ep.wMaxPacketSize;
                    } else {
                        ep_out = ep.bEndpointAddress;
                        mps_out = ep.wMaxPacketSize;
                    }
                }
            }
        }
        libusb_free_config_descriptor(cfg);
        if (ep_in == 0 || ep_out == 0) {
            why = name + ": interface " + std::to_string(kUsbInterface) + " has no bulk IN/OUT endpoint pair";
            return UsbStatus::io;
        }
        libusb_device_handle* h = nullptr;
        if (const int rc = libusb_open(dev, &h); rc != 0) {
            why = name + ": cannot open device: " + libusb_error_name(rc) +
                  (rc == LIBUSB_ERROR_ACCESS ? " (permission denied: add a udev rule for 1209:0001)" : "");
            return map_status(rc);
        }
        libusb_set_auto_detach_kernel_driver(h, 1);
        if (const int rc = libusb_claim_interface(h, kUsbInterface); rc != 0) {
            why = name + ": cannot claim interface " + std::to_string(kUsbInterface) + ": " + libusb_error_name(rc);
            libusb_close(h);
            return map_status(rc);
        }
        out = std::make_unique<LibusbDevice>(h, ep_in, ep_out, mps_in, mps_out);
        return UsbStatus::ok;
    }

    libusb_context* ctx_ = nullptr;
    libusb_hotplug_callback_handle hotplug_{};
    bool hotplug_ok_ = false;
    std::atomic<bool> arrived_{false};
};

}  // namespace

std::unique_ptr<UsbBackend> make_libusb_backend(const UsbIds& ids) { return std::make_unique<LibusbBackend>(ids); }

std::vector<UsbDeviceInfo> list_usb_devices(const UsbIds& ids) {
    LibusbBackend backend(ids);
    return backend.list(ids);
}

}  // namespace eyesim::transport
