# Sourced by the scripts run on a lent GPU machine (benches/lent/run.sh,
# benches/lent/tests.sh), after cd to the repository root and with kit set
# to the kit's path: unpacks the carried Vulkan loader where the machine
# lacks one (unpacking over libraries it has could break them), and points
# the loader at NVIDIA's driver file when wgpu sees no hardware adapter
# without it. Defines hardware (how many hardware GPUs the tool sees).
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp}
if ! ldconfig -p | grep -q 'libvulkan\.so\.1 '; then
    for f in "$kit"/gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
fi
hardware() { "$kit/bin/gsenc" devices --json | python3 -c 'import json, sys; print(json.load(sys.stdin)["hardware_gpus"])'; }
if [ "$(hardware)" = 0 ] && [ -f /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json ]; then
    export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
    export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
fi
# The GPU test binary finds data/ above the path it was built in.
built=$(cat "$kit/built-in")
if [ ! -e "$built" ]; then
    mkdir -p "$(dirname "$built")" && ln -s "$PWD" "$built"
fi
