# Shared by scripts/run and scripts/test: install what the project needs, idempotently and
# quietly when it is already there. Sourced, not executed.

# Packages listed one per line in the given files (# comments allowed).
list_packages() {
    sed -e 's/#.*//' -e '/^[[:space:]]*$/d' "$@"
}

# Installs the Debian packages that are not installed yet. Silent when none are missing.
ensure_apt() {
    local missing=() p
    for p in "$@"; do
        dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
    done
    if ((${#missing[@]})); then
        echo "mouthpiece: installing Debian packages: ${missing[*]}" >&2
        apt-get update -qq
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
    fi
}

# A Python virtualenv under target/ with the test references (numpy, scipy, mcap, …).
# Rebuilt from PyPI when missing or when the requirements file changed. Exports MOUTHPIECE_PYTHON.
ensure_python_venv() {
    local req=$1 venv=target/py
    local stamp="$venv/.requirements"
    if [[ ! -x "$venv/bin/python" ]] || ! cmp -s "$req" "$stamp"; then
        echo "mouthpiece: preparing Python test references in $venv" >&2
        python3 -m venv "$venv"
        "$venv/bin/pip" install -q --disable-pip-version-check -r "$req"
        cp "$req" "$stamp"
    fi
    MOUTHPIECE_PYTHON="$PWD/$venv/bin/python"
    export MOUTHPIECE_PYTHON
}

# The JavaScript test tools (tests/js: Khronos glTF-Validator), installed from the committed
# lock file into tests/js/node_modules; again only when the lock file changed. Node and npm
# come from Debian when no `npm` is on the PATH (a NodeSource `nodejs` bundles its own npm
# and conflicts with Debian's `npm` package).
ensure_js_test_tools() {
    local dir=$1
    local stamp="$dir/node_modules/.mouthpiece-lock"
    command -v npm >/dev/null || ensure_apt nodejs npm
    if ! cmp -s "$dir/package-lock.json" "$stamp"; then
        echo "mouthpiece: installing JavaScript test tools in $dir" >&2
        (cd "$dir" && npm ci --silent --no-audit --no-fund >/dev/null)
        cp "$dir/package-lock.json" "$stamp"
    fi
}
