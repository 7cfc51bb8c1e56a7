#!/bin/sh
# Patches the start script relx writes (bin/evatar and bin/evatar-VSN) in
# three places. Run by rebar3 after `release' and `tar' (rebar.config,
# post_hooks), with the profile's build directory in REBAR_BUILD_DIR; by
# hand:  scripts/patch-start-script.sh release|tar [BUILD_DIR]
#
#  - The nodetool helper's name. Every node name a node ever sees stays an
#    atom for good, and relx names the helper node of ping, rpc, eval,
#    stop, ... with USE_NODETOOL=1 (which TLS distribution needs)
#    `maint<random>-NAME': one or two atoms per command, so a health check
#    every 10 s fills the atom table in months. Patched, it takes one of
#    four fixed names, evatar_ctl1..4@HOST, the one whose lock it holds
#    (config/extensions/evatar_slot; README.md, "Operator commands").
#  - The files made from vm.args.src and sys.config.src at every command.
#    relx writes them in place, so a command that reads vm.args while
#    another command writes it found it empty ("need to have exactly one
#    of either -name or -sname parameters but none found"): about one in
#    ten of four commands run at once failed. Patched, each is written
#    under a name of its own, then renamed into place.
#
# Idempotent; fails (exit 1) when a line to patch is not found, so that a
# relx whose script changed is noticed at build time, not in the field.
set -eu

KIND=${1:-release}
BUILD=${2:-${REBAR_BUILD_DIR:-_build/default}}
REL=$(cd "$BUILD/rel/evatar" && pwd)

# patch FILE FROM TO: FROM, once in FILE, becomes TO (plain text).
patch() {
    file=$1 from=$2 to=$3
    if grep -qF -- "$to" "$file"; then
        return 0
    fi
    if [ "$(grep -cF -- "$from" "$file")" != 1 ]; then
        echo "patch-start-script: $file has no line $from: relx's start script changed; see scripts/patch-start-script.sh" >&2
        exit 1
    fi
    tmp=$file.patch.$$
    FROM=$from TO=$to awk '{ i = index($0, ENVIRON["FROM"])
                             if (i) $0 = substr($0, 1, i - 1) ENVIRON["TO"] substr($0, i + length(ENVIRON["FROM"]))
                             print }' "$file" > "$tmp"
    grep -qF -- "$to" "$tmp" || { rm -f "$tmp"; echo "patch-start-script: patching $file failed" >&2; exit 1; }
    chmod --reference="$file" "$tmp"
    mv "$tmp" "$file"
}

patch_script() {
    patch "$1" 'VMARGS_PATH=$(check_replace_os_vars vm.args "$VMARGS_PATH")' \
          '. "$SCRIPT_DIR/extensions/evatar_name"; VMARGS_PATH=$(check_replace_os_vars vm.args "$VMARGS_PATH")  # evatar: -name or -sname (scripts/patch-start-script.sh)'
    patch "$1" 'nodetool_id="maint$(relx_gen_id)-${NAME}"' \
          '. "$SCRIPT_DIR/extensions/evatar_slot"; nodetool_id="$EVATAR_CTL_NAME -dist_listen false"  # evatar: a fixed name (scripts/patch-start-script.sh)'
    patch "$1" "}1' < \"\$1\" > \"\$2\"" \
          "}1' < \"\$1\" > \"\$2.\$\$\" && mv -f \"\$2.\$\$\" \"\$2\"  # evatar: renamed into place (scripts/patch-start-script.sh)"
}

for script in "$REL"/bin/evatar "$REL"/bin/evatar-*; do
    if [ -f "$script" ]; then patch_script "$script"; fi
done

if [ "$KIND" = tar ]; then
    # The tarball was packed from the unpatched script: put the patched
    # one in its place.
    for tarball in "$REL"/evatar-*.tar.gz; do
        [ -f "$tarball" ] || continue
        work=$(mktemp -d)
        tar -xzf "$tarball" -C "$work"
        for script in "$work"/bin/evatar "$work"/bin/evatar-*; do
            if [ -f "$script" ]; then patch_script "$script"; fi
        done
        # Its entries, not `.': the directory mktemp made is mode 0700, and
        # `.' would give that mode to the directory the tarball is unpacked in.
        (cd "$work" && tar -czf "$tarball.new" -- *)
        mv "$tarball.new" "$tarball"
        rm -rf "$work"
    done
fi
