#!/usr/bin/env bash
# Run a command where SocketCAN works (the vcan module is loaded) and report its exit status.
#
#   tools/vcan-vm.sh COMMAND [ARGS...]
#   LEVELD_VM_SYSTEMD=1 tools/vcan-vm.sh COMMAND [ARGS...]
#
# With LEVELD_VM_SYSTEMD=1 the VM always runs (never this machine: the command may
# install packages and start services) and boots systemd as PID 1 on a writable
# overlay of this machine's root; the command runs as a oneshot service once the
# system is up, with a vcan named can0.
#
# If this machine's kernel can create vcan interfaces, the command runs here. If not
# (kernels built without CAN), it runs inside a small qemu VM under software
# emulation: Debian's kernel (fetched once and cached), a busybox initramfs that loads
# the CAN and 9p modules, and this machine's own root file system mounted read-only,
# with a tmpfs on /run as TMPDIR. The command runs as root in the current directory;
# its exit status is carried out of the VM.
set -euo pipefail
[ $# -ge 1 ] || { echo "usage: $0 COMMAND [ARGS...]" >&2; exit 2; }

as_root() { if [ "$(id -u)" = 0 ]; then "$@"; else sudo "$@"; fi; }

# Direct path: the kernel has vcan.
if [ -z "${LEVELD_VM_SYSTEMD:-}" ] && as_root ip link add dev leveldprobe0 type vcan 2>/dev/null; then
  as_root ip link del leveldprobe0
  echo "vcan-vm: host kernel has vcan; running directly" >&2
  exec "$@"
fi

cache=${LEVELD_VM_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/leveld-vm}
mkdir -p "$cache"

need=()
for c in qemu-system-x86_64:qemu-system-x86 busybox:busybox-static cpio:cpio depmod:kmod candump:can-utils ip:iproute2; do
  command -v "${c%%:*}" >/dev/null 2>&1 || need+=("${c##*:}")
done
if [ ${#need[@]} -gt 0 ]; then
  echo "vcan-vm: installing ${need[*]}" >&2
  as_root apt-get update -qq
  as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
fi
busybox=$(command -v busybox)
case "$(file -b "$busybox" 2>/dev/null || true)" in *dynamically*) busybox=/bin/busybox ;; esac
[ -x /bin/busybox ] && busybox=/bin/busybox

# Debian's kernel package, unpacked once.
kpkg=$(apt-cache depends linux-image-amd64 2>/dev/null | awk '/Depends: linux-image-[0-9]/ {print $2; exit}')
if [ -z "$kpkg" ]; then as_root apt-get update -qq; kpkg=$(apt-cache depends linux-image-amd64 | awk '/Depends: linux-image-[0-9]/ {print $2; exit}'); fi
kdir="$cache/$kpkg"
if [ ! -f "$kdir/.done" ]; then
  echo "vcan-vm: fetching $kpkg (cached in $cache)" >&2
  rm -rf "$kdir" && mkdir -p "$kdir"
  (cd "$kdir" && apt-get download "$kpkg" >/dev/null && dpkg-deb -x ./*.deb root && rm -f ./*.deb)
  touch "$kdir/.done"
fi
kver=${kpkg#linux-image-}
vmlinuz="$kdir/root/boot/vmlinuz-$kver"
mods="$kdir/root/lib/modules/$kver"

# Initramfs: busybox, the modules in load order, and the init script.
initrd="$cache/initrd-$kver.gz"
if [ ! -f "$initrd" ] || [ "$0" -nt "$initrd" ]; then
  work=$(mktemp -d)
  mkdir -p "$work"/{bin,dev,proc,sys,host,lib/modules}
  cp "$busybox" "$work/bin/busybox"
  order="can can-dev can-raw vcan virtio_ring virtio virtio_pci_modern_dev virtio_pci_legacy_dev virtio_pci 9pnet 9pnet_virtio netfs fscache 9p overlay"
  : > "$work/modules.order"
  for m in $order; do
    f=$(find "$mods" -name "$m.ko*" | head -n 1)
    [ -n "$f" ] || continue
    case "$f" in
      *.ko.xz) xz -dc "$f" > "$work/lib/modules/$m.ko" ;;
      *.ko.zst) zstd -qdc "$f" > "$work/lib/modules/$m.ko" ;;
      *) cp "$f" "$work/lib/modules/$m.ko" ;;
    esac
    echo "$m" >> "$work/modules.order"
  done
  cat > "$work/init" <<'INIT'
#!/bin/busybox sh
/bin/busybox --install -s /bin
mount -t proc proc /proc
mount -t sysfs sys /sys
mount -t devtmpfs dev /dev
for m in $(cat /modules.order); do insmod /lib/modules/$m.ko 2>/dev/null; done
out=$(sed -n 's/.*leveld.out=\([^ ]*\).*/\1/p' /proc/cmdline)
ip link set lo up
if grep -q 'leveld.systemd=1' /proc/cmdline; then
  # systemd as PID 1 on an overlay: this machine's root read-only below, tmpfs above.
  mkdir -p /lower /rw /newroot
  mount -t 9p -o trans=virtio,version=9p2000.L,msize=524288 host /lower || echo "vcan-vm: 9p root mount failed"
  mount -t tmpfs -o mode=0755 rw /rw
  mkdir -p /rw/upper /rw/work
  mount -t overlay overlay -o lowerdir=/lower,upperdir=/rw/upper,workdir=/rw/work /newroot || echo "vcan-vm: overlay mount failed"
  mkdir -p "/newroot$out"
  mount -t 9p -o trans=virtio,version=9p2000.L,msize=524288 out "/newroot$out" || echo "vcan-vm: 9p out mount failed"
  # The work tree at its own path, whatever systemd mounts over its parents (/tmp).
  work=$(sed -n 's/.*leveld.work=\([^ ]*\).*/\1/p' /proc/cmdline)
  mkdir -p "/newroot$work"
  mount -t 9p -o trans=virtio,version=9p2000.L,msize=524288,ro work "/newroot$work" || echo "vcan-vm: 9p work mount failed"
  ip link add dev can0 type vcan && ip link set up can0
  u=/newroot/etc/systemd/system
  mkdir -p "$u"
  printf '%s\n' '[Unit]' 'Description=leveld VM test' 'After=basic.target' \
    'SuccessAction=poweroff-force' 'FailureAction=poweroff-force' \
    '[Service]' 'Type=oneshot' "ExecStart=/bin/sh $out/run.sh" 'StandardOutput=journal+console' \
    'TimeoutStartSec=infinity' > "$u/leveld-vmtest.service"
  : > /newroot/etc/machine-id
  mount --move /proc /newroot/proc 2>/dev/null || umount /proc
  mount --move /sys /newroot/sys 2>/dev/null || umount /sys
  mount --move /dev /newroot/dev 2>/dev/null || true
  exec switch_root /newroot /lib/systemd/systemd systemd.unit=leveld-vmtest.service systemd.show_status=1
fi
mount -t 9p -o trans=virtio,version=9p2000.L,msize=524288 host /host || echo "vcan-vm: 9p root mount failed"
# Scratch space on /run; /tmp stays the host's, where the work tree may live.
mount -t tmpfs run /host/run
mkdir -p /host/run/leveld-tmp
mount -t 9p -o trans=virtio,version=9p2000.L,msize=524288 out "/host$out" || echo "vcan-vm: 9p out mount failed"
mount -o bind /proc /host/proc
mount -o bind /sys /host/sys
mount -o bind /dev /host/dev
mkdir -p /host/dev/pts 2>/dev/null; mount -t devpts pts /host/dev/pts 2>/dev/null
chroot /host /bin/sh "$out/run.sh"
echo "vcan-vm: exit status $?"
poweroff -f
INIT
  chmod +x "$work/init"
  (cd "$work" && find . | cpio -o -H newc 2>/dev/null | gzip -1) > "$initrd.tmp" && mv "$initrd.tmp" "$initrd"
  rm -rf "$work"
fi

# The command, with the caller's directory and environment that matters.
out=$(mktemp -d "${TMPDIR:-/tmp}/leveld-vm.XXXXXX")
out=$(realpath "$out")
{
  echo "set -u"
  echo "export PATH='$PATH' HOME=/root LANG=C.UTF-8 LEVELD_IN_VM=1 TMPDIR=/run/leveld-tmp"
  echo "mkdir -p /run/leveld-tmp"
  for v in RUST_BACKTRACE LEVELD_LOG CARGO_MANIFEST_DIR; do
    [ -n "${!v:-}" ] && printf 'export %s=%q\n' "$v" "${!v}"
  done
  echo "cd $(printf %q "$PWD")"
  printf '%q ' "$@"; echo ' > '"$out"'/stdout 2>&1'
  echo 'echo $? > '"$out"'/status'
} > "$out/run.sh"
cp "$out/run.sh" "$out/run.sh.kept"

cpus=$(nproc 2>/dev/null || echo 1)
echo "vcan-vm: booting $kver under qemu (TCG, $cpus vCPU)" >&2
timeout "${LEVELD_VM_TIMEOUT:-1500}" qemu-system-x86_64 -accel tcg -cpu max -smp "$cpus" -m 2048 \
  -nographic -no-reboot -kernel "$vmlinuz" -initrd "$initrd" \
  -virtfs local,path=/,mount_tag=host,security_model=none,readonly=on,multidevs=remap \
  -virtfs "local,path=$out,mount_tag=out,security_model=none" \
  -virtfs "local,path=$PWD,mount_tag=work,security_model=none,readonly=on,multidevs=remap" \
  -append "console=ttyS0 quiet panic=-1 leveld.out=$out leveld.work=$PWD${LEVELD_VM_SYSTEMD:+ leveld.systemd=1}" > "$out/console" 2>&1 || true

cat "$out/stdout" 2>/dev/null || true
if [ ! -f "$out/status" ]; then
  echo "vcan-vm: the command did not complete; console follows" >&2
  tail -n 40 "$out/console" >&2
  exit 125
fi
status=$(cat "$out/status")
rm -rf "$out"
exit "$status"
