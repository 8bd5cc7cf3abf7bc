#include "services/scanner/core/aravis_camera.h"

#include <arv.h>

#include <algorithm>
#include <stdexcept>

namespace picking::scanner {
namespace {

// Throws CameraError for a set GError, freeing it.
void Check(GError* error, const std::string& what) {
  if (error == nullptr) return;
  const std::string message = what + ": " + error->message;
  g_error_free(error);
  throw CameraError(message);
}

}  // namespace

struct AravisCamera::Impl {
  std::string device_id;
  ArvCamera* camera = nullptr;
  ArvStream* stream = nullptr;
  int buffer_count = 0;
  std::uint32_t width = 0;
  std::uint32_t height = 0;
  CameraSettings settings;
  bool configured = false;

  ~Impl() {
    if (camera != nullptr) Disarm();
    if (stream != nullptr) g_object_unref(stream);
    if (camera != nullptr) g_object_unref(camera);
  }

  int armed_count = 0;  // Frames the running acquisition was started for; 0 = stopped.

  std::string Name() const { return "camera '" + device_id + "'"; }

  // Stops a running acquisition (errors ignored: the camera may be gone).
  void Disarm() {
    if (armed_count == 0) return;
    armed_count = 0;
    GError* error = nullptr;
    arv_camera_stop_acquisition(camera, &error);
    g_clear_error(&error);
  }

  void CreateStream() {
    if (stream != nullptr) {
      g_object_unref(stream);
      stream = nullptr;
    }
    GError* error = nullptr;
    stream = arv_camera_create_stream(camera, nullptr, nullptr, &error);
    Check(error, Name() + ": cannot create the stream");
    if (stream == nullptr) throw CameraError(Name() + ": cannot create the stream");
    const guint payload = arv_camera_get_payload(camera, &error);
    Check(error, Name() + ": cannot read the payload size");
    if (ARV_IS_GV_STREAM(stream)) {
      // A GigE Vision frame arrives as a burst of UDP packets. The kernel charges each
      // packet's whole buffer (several times its payload for 1.5 kB packets) against the
      // socket's receive buffer, so the system default (about 200 kB) overflows within one
      // frame whenever the stream thread is not scheduled at once, and a loaded host then
      // drops frames. Room for several frames (the kernel caps it at net.core.rmem_max)
      // and resend requests for what is still lost keep frames whole.
      const guint64 wanted = 8ull * payload;
      const gint buffer_bytes = static_cast<gint>(wanted < (64ull << 20) ? wanted : (64ull << 20));
      g_object_set(G_OBJECT(stream), "socket-buffer", ARV_GV_STREAM_SOCKET_BUFFER_FIXED,
                   "socket-buffer-size", buffer_bytes, "packet-resend",
                   ARV_GV_STREAM_PACKET_RESEND_ALWAYS, nullptr);
    }
    for (int i = 0; i < buffer_count; ++i) {
      arv_stream_push_buffer(stream, arv_buffer_new_allocate(payload));
    }
  }
};

AravisCamera::AravisCamera(const std::string& device_id, int buffer_count)
    : impl_(std::make_unique<Impl>()) {
  if (buffer_count < 2) throw std::invalid_argument("AravisCamera: buffer_count must be >= 2");
  impl_->buffer_count = buffer_count;
  GError* error = nullptr;
  impl_->camera = arv_camera_new(device_id.empty() ? nullptr : device_id.c_str(), &error);
  impl_->device_id = device_id.empty() ? "<first camera>" : device_id;
  Check(error, "cannot open " + impl_->Name());
  if (impl_->camera == nullptr) throw CameraError("cannot open " + impl_->Name());
  if (device_id.empty()) {
    const char* id = arv_camera_get_device_id(impl_->camera, nullptr);
    if (id != nullptr) impl_->device_id = id;
  }
  arv_camera_set_pixel_format(impl_->camera, ARV_PIXEL_FORMAT_MONO_8, &error);
  Check(error, impl_->Name() + ": cannot set pixel format Mono8");
  gint x = 0, y = 0, width = 0, height = 0;
  arv_camera_get_region(impl_->camera, &x, &y, &width, &height, &error);
  Check(error, impl_->Name() + ": cannot read the image region");
  impl_->width = static_cast<std::uint32_t>(width);
  impl_->height = static_cast<std::uint32_t>(height);
  arv_camera_set_acquisition_mode(impl_->camera, ARV_ACQUISITION_MODE_CONTINUOUS, &error);
  Check(error, impl_->Name() + ": cannot set continuous acquisition");
  impl_->CreateStream();
}

AravisCamera::~AravisCamera() = default;

std::uint32_t AravisCamera::width() const { return impl_->width; }
std::uint32_t AravisCamera::height() const { return impl_->height; }
const std::string& AravisCamera::device_id() const { return impl_->device_id; }

void AravisCamera::Configure(const CameraSettings& settings) {
  ValidateCameraSettings(settings);
  impl_->Disarm();
  GError* error = nullptr;
  ArvCamera* camera = impl_->camera;
  arv_camera_set_exposure_time(camera, settings.exposure_us, &error);
  Check(error,
        impl_->Name() + ": cannot set exposure " + std::to_string(settings.exposure_us) + " us");
  switch (settings.trigger_mode) {
    case TriggerMode::kFreeRun:
      arv_camera_clear_triggers(camera, &error);
      Check(error, impl_->Name() + ": cannot switch triggers off");
      break;
    case TriggerMode::kSoftware:
      arv_camera_set_trigger(camera, "Software", &error);
      Check(error, impl_->Name() + ": cannot set software trigger");
      break;
    case TriggerMode::kHardware:
      arv_camera_set_trigger(camera, settings.hardware_trigger_line.c_str(), &error);
      Check(error, impl_->Name() + ": cannot set hardware trigger on '" +
                       settings.hardware_trigger_line + "'");
      break;
  }
  if (ARV_IS_GV_STREAM(impl_->stream)) {
    // Aravis gives a GigE frame up (buffer status TIMEOUT) when no packet of it has come for
    // the frame retention, 100 ms by default: a camera process or link stalled that long on
    // a loaded host is not a lost frame yet. Half the frame timeout leaves the other half for
    // the transfer, so an incomplete frame is reported before Capture stops waiting for it.
    const double retention_us = std::min(settings.frame_timeout_s * 0.5e6, 60e6);
    g_object_set(G_OBJECT(impl_->stream), "frame-retention",
                 static_cast<guint>(std::max(retention_us, 1.0)), nullptr);
  }
  impl_->settings = settings;
  impl_->configured = true;
}

void AravisCamera::Arm(int count) {
  if (count <= 0) {
    throw std::invalid_argument("AravisCamera::Arm: count must be > 0, got " +
                                std::to_string(count));
  }
  if (!impl_->configured) throw CameraError(impl_->Name() + ": Arm before Configure");
  impl_->Disarm();
  // Frames left over from an earlier capture are stale: give their buffers back.
  while (ArvBuffer* stale = arv_stream_try_pop_buffer(impl_->stream))
    arv_stream_push_buffer(impl_->stream, stale);
  GError* error = nullptr;
  arv_camera_start_acquisition(impl_->camera, &error);
  Check(error, impl_->Name() + ": cannot start the acquisition");
  impl_->armed_count = count;
}

std::vector<Frame> AravisCamera::Capture(int count) {
  if (count <= 0) {
    throw std::invalid_argument("AravisCamera::Capture: count must be > 0, got " +
                                std::to_string(count));
  }
  if (!impl_->configured) throw CameraError(impl_->Name() + ": Capture before Configure");
  if (impl_->armed_count != count) Arm(count);
  ArvCamera* camera = impl_->camera;
  ArvStream* stream = impl_->stream;
  GError* error = nullptr;
  std::vector<Frame> frames;
  frames.reserve(static_cast<std::size_t>(count));
  // A frame takes its exposure plus the readout; the timeout bounds the readout and transfer.
  const double wait_s = impl_->settings.frame_timeout_s + impl_->settings.exposure_us * 1e-6;
  const auto timeout_us = static_cast<guint64>(wait_s * 1e6);
  std::string failure;
  bool timed_out = false;
  bool incomplete = false;
  const bool software = impl_->settings.trigger_mode == TriggerMode::kSoftware;
  // Ids of the whole frames, in runs between frames taken again: an incomplete frame may not
  // know its id (its leader packet lost), and the frame taken after it is the one triggered,
  // so the ids are checked within each run.
  std::vector<std::vector<std::uint64_t>> runs(1);
  int retries_left = impl_->settings.dropped_frame_retries;
  for (int i = 0; i < count && failure.empty();) {
    if (software) {
      arv_camera_software_trigger(camera, &error);
      if (error != nullptr) {
        failure = impl_->Name() + ": software trigger failed: " + error->message;
        g_clear_error(&error);
        break;
      }
    }
    ArvBuffer* buffer = arv_stream_timeout_pop_buffer(stream, timeout_us);
    if (buffer == nullptr) {
      timed_out = true;
      failure = impl_->Name() + ": frame " + std::to_string(i) + " of " + std::to_string(count) +
                " did not arrive within " + std::to_string(wait_s) + " s" +
                (impl_->settings.trigger_mode == TriggerMode::kHardware
                     ? " (hardware trigger on '" + impl_->settings.hardware_trigger_line +
                           "': is the projector's trigger output connected and running?)"
                     : "");
      break;
    }
    const ArvBufferStatus status = arv_buffer_get_status(buffer);
    if (status == ARV_BUFFER_STATUS_MISSING_PACKETS || status == ARV_BUFFER_STATUS_TIMEOUT ||
        status == ARV_BUFFER_STATUS_ABORTED) {
      arv_stream_push_buffer(stream, buffer);
      // The scene of a software-triggered frame is still there: take it again. A frame lost
      // after its hardware trigger is gone with its pattern.
      if (software && retries_left > 0) {
        --retries_left;
        if (!runs.back().empty()) runs.emplace_back();
        continue;
      }
      incomplete = true;
      failure =
          impl_->Name() + ": dropped frame: frame " + std::to_string(i) + " of " +
          std::to_string(count) + " arrived incomplete (buffer status " +
          std::to_string(static_cast<int>(status)) + ")" +
          (software ? " after " + std::to_string(impl_->settings.dropped_frame_retries) + " retries"
                    : "");
      break;
    }
    if (status != ARV_BUFFER_STATUS_SUCCESS) {
      failure = impl_->Name() + ": frame " + std::to_string(i) + " has buffer status " +
                std::to_string(static_cast<int>(status));
    } else {
      size_t size = 0;
      const auto* data = static_cast<const std::uint8_t*>(arv_buffer_get_image_data(buffer, &size));
      const auto w = static_cast<std::uint32_t>(arv_buffer_get_image_width(buffer));
      const auto h = static_cast<std::uint32_t>(arv_buffer_get_image_height(buffer));
      if (data == nullptr || size < static_cast<size_t>(w) * h) {
        failure = impl_->Name() + ": frame " + std::to_string(i) + " is shorter than " +
                  std::to_string(w) + " x " + std::to_string(h) + " Mono8 pixels";
      } else {
        Frame frame;
        frame.image = GrayImage(w, h);
        std::copy(data, data + static_cast<std::size_t>(w) * h, frame.image.pixels.begin());
        frame.frame_id = arv_buffer_get_frame_id(buffer);
        runs.back().push_back(frame.frame_id);
        frame.timestamp_s = static_cast<double>(arv_buffer_get_timestamp(buffer)) * 1e-9;
        frames.push_back(std::move(frame));
        ++i;
        retries_left = impl_->settings.dropped_frame_retries;
      }
    }
    arv_stream_push_buffer(stream, buffer);
  }
  impl_->Disarm();
  if (timed_out) throw CameraTimeoutError(failure);
  if (incomplete) throw DroppedFrameError(failure);
  if (!failure.empty()) throw CameraError(failure);
  for (const auto& run : runs) CheckConsecutiveFrameIds(run);
  return frames;
}

std::string EnableAravisFakeCamera() {
  arv_enable_interface("Fake");
  arv_update_device_list();
  const unsigned int n = arv_get_n_devices();
  for (unsigned int i = 0; i < n; ++i) {
    const char* protocol = arv_get_device_protocol(i);
    const char* id = arv_get_device_id(i);
    if (protocol != nullptr && id != nullptr && std::string(protocol) == "Fake") return id;
  }
  throw CameraError("the Aravis fake camera did not appear after enabling the Fake interface");
}

std::vector<std::string> ListAravisCameras() {
  arv_update_device_list();
  std::vector<std::string> ids;
  const unsigned int n = arv_get_n_devices();
  for (unsigned int i = 0; i < n; ++i) {
    const char* id = arv_get_device_id(i);
    if (id != nullptr) ids.emplace_back(id);
  }
  return ids;
}

}  // namespace picking::scanner
