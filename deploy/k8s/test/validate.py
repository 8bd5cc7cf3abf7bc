#!/usr/bin/env python3
"""Offline validation of the Kubernetes manifests under deploy/k8s (the CTest test k8s_manifests).

For the base and each overlay it
  1. renders the kustomization (kustomize_lite.py; where a kustomize v4 or later is at hand,
     as `kustomize` or in `kubectl`, it renders with that too and requires the same objects),
  2. validates every object against the Kubernetes 1.27 JSON schemas kept in
     deploy/k8s/schemas/, made strict: an unknown field, a wrong type, a malformed quantity or
     an out-of-range integer fails,
  3. checks what the project needs of them: each container runs one of the project's
     binaries; each server listens on 50051 and is probed there with gRPC (its health
     service; by TCP only where it runs mutual TLS, which the kubelet's gRPC probes cannot
     speak) and readiness names its service; its --config file comes from a mounted
     ConfigMap and holds only settings the server documents; the orchestrator reaches the
     detector through dns:/// on a headless Service and every other peer through a Service
     of the right server; Service selectors, Deployment selectors and pod labels agree;
     every volume, ConfigMap, Secret and claim referred to exists; grace periods cover the
     servers' shutdown; the pods run as non-root without privileges, with resources set;
     paths into the image's data exist in data/.

  validate.py [--kustomize=auto|off|require]   # the check, exit status 1 on any failure
  validate.py --self-test                      # breaks the manifests in known ways and
                                               # requires the check to catch each one

Run with Debian's /usr/bin/python3 (python3-yaml, python3-jsonschema).
"""
import copy
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile

import jsonschema
import yaml

HERE = os.path.dirname(os.path.abspath(__file__))
K8S = os.path.dirname(HERE)
ROOT = os.path.dirname(os.path.dirname(K8S))
sys.path.insert(0, HERE)
import kustomize_lite  # noqa: E402

TARGETS = ["base", "overlays/sim", "overlays/tls", "overlays/single-node"]
SCHEMA_FILE = os.path.join(K8S, "schemas", "kubernetes-1.27.1.json")
PORT = 50051
IMAGE_DATA = "/opt/picking/data/"
# Flags of the server runtime (libs/runtime/server.cc) and of mutual TLS; any other
# --key=value is a setting.
RUNTIME_FLAGS = {"listen", "config", "log-level", "shutdown-grace-s", "max-message-mb"}
TLS_FLAGS = {"tls.cert", "tls.key", "tls.ca"}
# The command line's (clients/cli): an option and its value as two arguments.
CLI_TLS_OPTIONS = {"--tls-cert", "--tls-key", "--tls-ca"}
# The certificates scripts/make-certs.sh makes for overlays/tls: one per Service, and the
# command line's.
CERT_NAMES = ["simulator", "robot", "gripper", "scanner", "detector", "planner",
              "orchestrator", "viewer", "picking"]
DEFAULT_GRACE_S = 5.0
# Servers that own something single (the world, the arm, the vacuum, the camera, the tasks
# volume): one replica.
SINGLE_REPLICA = {"picking-simulator", "picking-robot", "picking-gripper", "picking-scanner",
                  "picking-orchestrator"}


class Failures:
    def __init__(self):
        self.items = []

    def __call__(self, where, message):
        self.items.append(f"{where}: {message}")


# --- what the project defines -----------------------------------------------------------------

def project_binaries():
    names = set()
    for top in ("services", "clients"):
        for sub in sorted(os.listdir(os.path.join(ROOT, top))):
            path = os.path.join(ROOT, top, sub, "CMakeLists.txt")
            if os.path.isfile(path):
                with open(path, encoding="utf-8") as f:
                    names |= set(re.findall(r"picking_executable\(\s*NAME\s+(\S+)", f.read()))
    return names


def service_full_names():
    """picking-<name> -> its gRPC service's full name, from proto/picking/<name>/v1."""
    out = {}
    base = os.path.join(ROOT, "proto", "picking")
    for name in sorted(os.listdir(base)):
        folder = os.path.join(base, name, "v1")
        if not os.path.isdir(folder):
            continue
        for proto in sorted(os.listdir(folder)):
            with open(os.path.join(folder, proto), encoding="utf-8") as f:
                text = f.read()
            pkg = re.search(r"^package\s+([\w.]+);", text, re.M)
            svc = re.search(r"^service\s+(\w+)\s*\{", text, re.M)
            if pkg and svc:
                out[f"picking-{name}"] = f"{pkg.group(1)}.{svc.group(1)}"
    return out


def documented_settings():
    """picking-<name> -> the settings docs/services.md lists in that server's tables."""
    with open(os.path.join(ROOT, "docs", "services.md"), encoding="utf-8") as f:
        text = f.read()
    out = {}
    for section in re.split(r"^## ", text, flags=re.M)[1:]:
        title = section.split("\n", 1)[0].strip()
        if not title.startswith("picking-"):
            continue
        keys = set()
        for line in section.splitlines():
            if line.startswith("| `"):
                keys |= set(re.findall(r"`([^`]+)`", line.split("|")[1]))
        out[title] = keys
    return out


def setting_known(key, documented):
    for doc in documented:
        # Upper-case parts are placeholders (safety.zone.NAME.min_m).
        pattern = "".join("[^.]+" if p.isupper() else re.escape(p)
                          for p in re.split(r"([A-Z]+)", doc) if p)
        if re.fullmatch(pattern, key):
            return True
    return False


def flatten(value, prefix=""):
    """A server's config file as its runtime reads it: nested mappings as dotted keys."""
    out = {}
    if isinstance(value, dict):
        for k, v in value.items():
            out.update(flatten(v, f"{prefix}.{k}" if prefix else str(k)))
    elif isinstance(value, list):
        out[prefix] = ",".join(str(v) for v in value)
    elif value is None:
        out[prefix] = ""
    else:
        out[prefix] = str(value).lower() if isinstance(value, bool) else str(value)
    return out


# --- schemas --------------------------------------------------------------------------------

def load_schemas():
    with open(SCHEMA_FILE, encoding="utf-8") as f:
        bundle = json.load(f)

    def strict(node):
        if isinstance(node, dict):
            if "$ref" in node:
                ref = node["$ref"]
                node["$ref"] = "#/definitions/" + ref[:-1] if ref.endswith("#") else ref
            if "properties" in node and "additionalProperties" not in node:
                node["additionalProperties"] = False
            for v in node.values():
                strict(v)
        elif isinstance(node, list):
            for v in node:
                strict(v)

    definitions = copy.deepcopy(bundle["definitions"])
    strict(definitions)
    return bundle["kinds"], definitions


QUANTITY = re.compile(r"^[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+|Ki|Mi|Gi|Ti|Pi|Ei|[numkMGTPE])?$")


def format_checker():
    checker = jsonschema.FormatChecker(formats=())

    @checker.checks("int32")
    def int32(v):
        return not isinstance(v, int) or -2**31 <= v < 2**31

    @checker.checks("int64")
    def int64(v):
        return not isinstance(v, int) or -2**63 <= v < 2**63

    @checker.checks("double")
    def double(v):
        return True

    @checker.checks("quantity")
    def quantity(v):
        return not isinstance(v, str) or bool(QUANTITY.match(v))

    @checker.checks("byte")
    def byte(v):
        import base64
        import binascii
        if not isinstance(v, str):
            return True
        try:
            # Long values come in lines (as kustomize writes them).
            base64.b64decode(v.replace("\n", ""), validate=True)
            return True
        except binascii.Error:
            return False

    @checker.checks("date-time")
    def date_time(v):
        return not isinstance(v, str) or bool(
            re.match(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(\.\d+)?(Z|[+-]\d\d:\d\d)$", v))

    return checker


def deepest(error):
    """The most telling error: inside oneOf / anyOf, the branch that got furthest (deepest,
    and of the right type: a string quantity is told it is malformed, not that it is no
    number)."""
    while error.context:
        error = max(error.context, key=lambda e: (len(e.absolute_path), e.validator != "type",
                                                  -len(e.context)))
    return error


def validate_schema(obj, kinds, definitions, checker, fail, where):
    key = f"{obj.get('apiVersion')}/{obj.get('kind')}"
    if key not in kinds:
        fail(where, f"kind {key} has no schema in deploy/k8s/schemas (add it to "
                    "extract-schemas.js and extract again)")
        return
    schema = {"$ref": f"#/definitions/{kinds[key]}", "definitions": definitions}
    validator = jsonschema.Draft7Validator(schema, format_checker=checker)
    for error in sorted(validator.iter_errors(obj), key=lambda e: list(e.absolute_path)):
        e = deepest(error)
        path = "/".join(str(p) for p in e.absolute_path)
        fail(where, f"schema: at /{path}: {e.message}")


# --- project checks -------------------------------------------------------------------------

def parse_quantity(q):
    q = str(q)
    m = QUANTITY.match(q)
    if not m:
        return None
    suffixes = {"Ki": 2**10, "Mi": 2**20, "Gi": 2**30, "Ti": 2**40, "Pi": 2**50, "Ei": 2**60,
                "n": 1e-9, "u": 1e-6, "m": 1e-3, "k": 1e3, "M": 1e6, "G": 1e9, "T": 1e12,
                "P": 1e15, "E": 1e18}
    number = float(q[:m.start(3)] if m.group(3) else q)
    suffix = m.group(3) or ""
    if suffix and suffix[0] in "eE":
        return float(q)
    return number * suffixes.get(suffix, 1)


def flags_of(args):
    """--key=value flags of a server's args, in order (a later one wins, as in the runtime)."""
    out = {}
    for a in args:
        if a.startswith("--") and "=" in a:
            k, v = a[2:].split("=", 1)
            out[k] = v
    return out


def labels_match(selector, labels):
    return bool(selector) and all(labels.get(k) == v for k, v in selector.items())


def image_path_exists(value):
    rel = value[len(IMAGE_DATA):]
    return os.path.exists(os.path.join(ROOT, "data", rel))


def check_data_paths(value, fail, where):
    if isinstance(value, str) and value.startswith(IMAGE_DATA) and not image_path_exists(value):
        fail(where, f"{value}: no such file in the image (data/{value[len(IMAGE_DATA):]})")


def mounted_file(spec, container, path, volume_kind):
    """The (volume, key) that puts the file `path` into the container from a configMap or
    secret volume (the key of the ConfigMap or Secret, through the volume's items if any)."""
    volumes = {v["name"]: v for v in spec.get("volumes", []) or []}
    for m in container.get("volumeMounts", []) or []:
        mount = m["mountPath"].rstrip("/")
        if os.path.dirname(path) == mount and m["name"] in volumes:
            vol = volumes[m["name"]]
            if volume_kind not in vol:
                continue
            items = vol[volume_kind].get("items")
            if not items:
                return vol, os.path.basename(path)
            for item in items:
                if item["path"] == os.path.basename(path):
                    return vol, item["key"]
    return None, None


def check_tls_files(pod, container, files, owner, find, ns, fail, where):
    """`files`: {option: path} of the certificate, key and CA; each must come from a mounted
    Secret, the certificate and key being `owner`'s (its DNS name: what the clients dial)."""
    for option, path in sorted(files.items()):
        vol, key = mounted_file(pod, container, path, "secret")
        if vol is None:
            fail(where, f"{option} {path}: not in a mounted Secret")
            continue
        secret = find("Secret", vol["secret"]["secretName"], ns)
        if secret is None:
            fail(where, f"Secret {vol['secret']['secretName']} does not exist")
            continue
        if key not in (secret.get("data") or {}):
            fail(where, f"Secret {vol['secret']['secretName']} has no key {key}")
        role = "cert" if "cert" in option else "key" if "key" in option else "ca"
        wanted = {"cert": f"{owner}.crt", "key": f"{owner}.key", "ca": "ca.crt"}[role]
        if key != wanted:
            fail(where, f"{option} {path} holds the Secret's {key}, not {wanted}: the "
                        f"certificate must name {owner}, the name its peers dial")


def check_objects(objects, fail, label, binaries, full_names, documented):
    by_kind = {}
    for o in objects:
        by_kind.setdefault(o["kind"], []).append(o)

    def find(kind, name, ns):
        for o in by_kind.get(kind, []):
            if o["metadata"]["name"] == name and o["metadata"].get("namespace", "") == ns:
                return o
        return None

    deployments = by_kind.get("Deployment", [])
    services = by_kind.get("Service", [])

    def binary_of(dep):
        c = dep["spec"]["template"]["spec"]["containers"]
        return (c[0].get("command") or [None])[0] if c else None

    def service_for(host, port, ns, where, binary=None, headless=None):
        svc = find("Service", host, ns)
        if svc is None:
            fail(where, f"no Service '{host}' for {host}:{port}")
            return None
        if not any(p.get("port") == port for p in svc["spec"].get("ports", [])):
            fail(where, f"Service {host} has no port {port}")
        if headless is True and svc["spec"].get("clusterIP") != "None":
            fail(where, f"Service {host} must be headless (clusterIP: None) for a dns:/// "
                        "target: a cluster IP would send every call to one pod")
        if headless is False and svc["spec"].get("clusterIP") == "None":
            fail(where, f"Service {host} is headless; a single-address peer needs a ClusterIP")
        targets = [d for d in deployments if d["metadata"].get("namespace", "") == ns and
                   labels_match(svc["spec"].get("selector"),
                                d["spec"]["template"]["metadata"].get("labels", {}))]
        if binary and not any(binary_of(d) == binary for d in targets):
            fail(where, f"Service {host} does not select a Deployment running {binary}")
        return svc

    namespaces = {o["metadata"].get("namespace", "") for o in objects
                  if o["kind"] not in kustomize_lite.CLUSTER_SCOPED}
    if len(namespaces) != 1:
        fail(label, f"objects in several namespaces: {sorted(namespaces)}")
    ns_name = next(iter(namespaces)) if len(namespaces) == 1 else ""
    if ns_name and find("Namespace", ns_name, "") is None:
        fail(label, f"namespace {ns_name} is used but not created")

    tls_servers = 0
    for dep in deployments:
        where = f"{label}: Deployment {dep['metadata']['name']}"
        ns = dep["metadata"].get("namespace", "")
        spec = dep["spec"]
        tmpl = spec["template"]
        pod = tmpl["spec"]
        labels = tmpl["metadata"].get("labels", {})
        if not labels_match(spec["selector"].get("matchLabels"), labels):
            fail(where, "spec.selector.matchLabels does not match the pod template's labels")
        containers = pod.get("containers", [])
        if len(containers) != 1:
            fail(where, "one container per server pod expected")
            continue
        c = containers[0]
        command = c.get("command") or []
        binary = command[0] if command else None
        if len(command) != 1 or binary not in binaries or not binary.startswith("picking-"):
            fail(where, f"command {command}: not one of the project's servers "
                        f"({', '.join(sorted(b for b in binaries if b.startswith('picking-')))})")
            continue
        server = binary[len("picking-"):]
        if dep["metadata"]["name"] != server:
            fail(where, f"runs {binary}: the Deployment and its Service must be named {server} "
                        "(the names the orchestrator's defaults dial)")
        args = c.get("args", []) or []
        for a in args:
            if not (a.startswith("--") and "=" in a):
                fail(where, f"argument '{a}': the servers take --key=value only")
        flags = flags_of(args)
        if flags.get("listen") != f"0.0.0.0:{PORT}":
            fail(where, f"--listen must be 0.0.0.0:{PORT}, is {flags.get('listen')}")
        if not any(p.get("containerPort") == PORT for p in c.get("ports", []) or []):
            fail(where, f"no containerPort {PORT}")
        replicas = spec.get("replicas", 1)
        if binary in SINGLE_REPLICA and replicas != 1:
            fail(where, f"{binary} owns its part of the cell: exactly one replica, not {replicas}")

        tls = TLS_FLAGS & set(flags)
        if tls and tls != TLS_FLAGS:
            fail(where, f"TLS needs all of {sorted(TLS_FLAGS)}, has {sorted(tls)}")
        if tls:
            tls_servers += 1
            check_tls_files(pod, c, {f"--{k}": flags[k] for k in tls}, server, find, ns, fail,
                            where)

        for probe_name in ("startupProbe", "readinessProbe", "livenessProbe"):
            probe = c.get(probe_name)
            if probe is None:
                if probe_name != "startupProbe":
                    fail(where, f"no {probe_name}")
                continue
            handlers = {h for h in ("grpc", "httpGet", "tcpSocket", "exec") if h in probe}
            if tls:
                if handlers != {"tcpSocket"} or probe["tcpSocket"].get("port") != PORT:
                    fail(where, f"{probe_name}: with mutual TLS the probe is tcpSocket on "
                                f"{PORT} (the kubelet's gRPC probe has no TLS), got {probe}")
                continue
            if handlers != {"grpc"} or probe["grpc"].get("port") != PORT:
                fail(where, f"{probe_name} must be grpc on port {PORT} (the servers' "
                            f"grpc.health.v1 service), got {probe}")
                continue
            service = probe["grpc"].get("service", "")
            # A server without a contract of its own (the viewer) is probed as a whole ("").
            own = full_names.get(binary, "")
            if service not in ("", own):
                fail(where, f"{probe_name}: grpc.service '{service}' is not {binary}'s "
                            f"service {own}")
            if probe_name == "readinessProbe" and service != own:
                fail(where, f"readinessProbe must name the service {own}")

        # Settings: the config file (a mounted ConfigMap) and --key=value overrides.
        settings = {}
        if "config" in flags:
            vol, key = mounted_file(pod, c, flags["config"], "configMap")
            if vol is None:
                fail(where, f"--config={flags['config']}: not in a mounted ConfigMap")
            else:
                cm = find("ConfigMap", vol["configMap"]["name"], ns)
                if cm is None:
                    fail(where, f"ConfigMap {vol['configMap']['name']} does not exist")
                elif key not in (cm.get("data") or {}):
                    fail(where, f"ConfigMap {vol['configMap']['name']} has no key {key}")
                else:
                    try:
                        loaded = yaml.safe_load(cm["data"][key]) or {}
                    except yaml.YAMLError as e:
                        fail(where, f"{key}: not YAML: {e}")
                        loaded = {}
                    if not isinstance(loaded, dict):
                        fail(where, f"{key}: not a mapping of settings")
                        loaded = {}
                    settings.update(flatten(loaded))
        settings.update({k: v for k, v in flags.items()
                         if k not in RUNTIME_FLAGS and k not in TLS_FLAGS})
        docs = documented.get(binary, set())
        for k, v in sorted(settings.items()):
            if not setting_known(k, docs):
                fail(where, f"setting '{k}' is not one of {binary}'s (docs/services.md): the "
                            "server would refuse to start (exit status 2)")
            check_data_paths(v, fail, f"{where}: setting {k}")
        for a in args:
            check_data_paths(a.split("=", 1)[-1], fail, where)

        # Peers named by address: a Service of the right server on that port.
        peers = {"sim.address": "picking-simulator", "robot.address": "picking-robot",
                 "scanner.address": "picking-scanner", "planner.address": "picking-planner",
                 "gripper.address": "picking-gripper",
                 "orchestrator.address": "picking-orchestrator"}
        if binary == "picking-orchestrator":
            for name in ("scanner", "planner", "robot", "gripper"):
                settings.setdefault(f"{name}.address", f"{name}:{PORT}")
            settings.setdefault("detector.endpoints", f"dns:///detector:{PORT}")
            endpoints = settings["detector.endpoints"]
            m = re.fullmatch(r"dns:///([a-z0-9-]+):(\d+)", endpoints)
            if not m:
                fail(where, f"detector.endpoints '{endpoints}' must be dns:///SERVICE:{PORT}, "
                            "a headless Service resolving to every detector pod")
            else:
                service_for(m.group(1), int(m.group(2)), ns, where, "picking-detector",
                            headless=True)
        for k, peer in peers.items():
            v = settings.get(k)
            if v is None or (binary in ("picking-robot", "picking-gripper") and
                             k == "sim.address" and settings.get("backend", "sim") != "sim"):
                continue
            m = re.fullmatch(r"([a-z0-9-]+):(\d+)", v)
            if not m:
                fail(where, f"setting {k}={v}: not SERVICE:PORT of a Service in the cell")
                continue
            service_for(m.group(1), int(m.group(2)), ns, f"{where}: {k}", peer, headless=False)

        # Shutdown: the kill comes after the servers' own grace period (and the
        # orchestrator's wait for a task's step).
        grace = float(flags.get("shutdown-grace-s", DEFAULT_GRACE_S))
        needed = grace + (float(settings.get("shutdown_wait_s", 3.0))
                          if binary == "picking-orchestrator" else 0.0)
        period = pod.get("terminationGracePeriodSeconds", 30)
        if period < needed + 2:
            fail(where, f"terminationGracePeriodSeconds {period} leaves no margin over the "
                        f"server's {needed:g} s of shutdown")

    # The pods, servers and jobs alike.
    pod_objects = deployments + by_kind.get("Job", [])
    for o in pod_objects:
        where = f"{label}: {o['kind']} {o['metadata']['name']}"
        ns = o["metadata"].get("namespace", "")
        pod = o["spec"]["template"]["spec"]
        sc = pod.get("securityContext", {}) or {}
        if sc.get("runAsNonRoot") is not True or not isinstance(sc.get("runAsUser"), int) \
                or sc.get("runAsUser", 0) <= 0:
            fail(where, "the pod must run as a numeric non-root uid (runAsNonRoot, runAsUser)")
        if (sc.get("seccompProfile") or {}).get("type") != "RuntimeDefault":
            fail(where, "seccompProfile RuntimeDefault (restricted Pod Security Standard)")
        volumes = {v["name"]: v for v in pod.get("volumes", []) or []}
        for v in volumes.values():
            if "configMap" in v and find("ConfigMap", v["configMap"]["name"], ns) is None:
                fail(where, f"volume {v['name']}: ConfigMap {v['configMap']['name']} missing")
            if "secret" in v and find("Secret", v["secret"]["secretName"], ns) is None:
                fail(where, f"volume {v['name']}: Secret {v['secret']['secretName']} missing")
            if "persistentVolumeClaim" in v and find(
                    "PersistentVolumeClaim", v["persistentVolumeClaim"]["claimName"], ns) is None:
                fail(where, f"volume {v['name']}: claim "
                            f"{v['persistentVolumeClaim']['claimName']} missing")
        for c in pod.get("containers", []) + (pod.get("initContainers", []) or []):
            cw = f"{where} container {c['name']}"
            command = c.get("command") or []
            if not command or command[0] not in binaries:
                fail(cw, f"command {command}: not one of the project's binaries "
                         f"{sorted(binaries)}")
            if not c.get("image", "").split("/")[-1].startswith("picking"):
                fail(cw, f"image {c.get('image')}: the project's image is picking")
            csc = c.get("securityContext", {}) or {}
            if csc.get("allowPrivilegeEscalation") is not False or \
                    "ALL" not in ((csc.get("capabilities") or {}).get("drop") or []):
                fail(cw, "allowPrivilegeEscalation false and capabilities drop ALL")
            if csc.get("readOnlyRootFilesystem") is not True:
                fail(cw, "readOnlyRootFilesystem true (writable volumes where needed)")
            for m in c.get("volumeMounts", []) or []:
                if m["name"] not in volumes:
                    fail(cw, f"volumeMount {m['name']}: no such volume")
            res = c.get("resources", {}) or {}
            for r in ("cpu", "memory"):
                req = (res.get("requests") or {}).get(r)
                lim = (res.get("limits") or {}).get(r)
                if req is None or lim is None:
                    fail(cw, f"resources: requests and limits of {r} expected")
                elif (parse_quantity(req) or 0) > (parse_quantity(lim) or 0):
                    fail(cw, f"resources: {r} request {req} above its limit {lim}")

    for job in by_kind.get("Job", []):
        where = f"{label}: Job {job['metadata']['name']}"
        ns = job["metadata"].get("namespace", "")
        c = job["spec"]["template"]["spec"]["containers"][0]
        args = c.get("args", []) or []
        if (c.get("command") or [None])[0] == "picking":
            if not args or args[0] not in ("run", "watch", "status", "list", "cancel", "score"):
                fail(where, f"picking {args[:1]}: not a command of the CLI")
            if args[:1] == ["run"] and (len(args) < 2 or args[1].startswith("--")):
                fail(where, "picking run needs a task file")
            for a in args:
                check_data_paths(a, fail, where)
            if "--address" in args:
                i = args.index("--address")
                m = re.fullmatch(r"([a-z0-9-]+):(\d+)", args[i + 1] if i + 1 < len(args) else "")
                if not m:
                    fail(where, "--address must be SERVICE:PORT")
                else:
                    service_for(m.group(1), int(m.group(2)), ns, where,
                                "picking-orchestrator", headless=False)
            else:
                fail(where, "picking needs --address orchestrator:50051 (its default is "
                            "localhost:50050)")
            cli_tls = {a: args[i + 1] for i, a in enumerate(args[:-1]) if a in CLI_TLS_OPTIONS}
            if tls_servers and set(cli_tls) != CLI_TLS_OPTIONS:
                fail(where, "the servers run mutual TLS: the command line needs "
                            f"{sorted(CLI_TLS_OPTIONS)}")
            elif cli_tls:
                check_tls_files(job["spec"]["template"]["spec"], c, cli_tls, "picking", find, ns,
                                fail, where)
        rules = (job["spec"].get("podFailurePolicy") or {}).get("rules", [])
        for r in rules:
            name = (r.get("onExitCodes") or {}).get("containerName")
            if name and name != c["name"]:
                fail(where, f"podFailurePolicy names container {name}, not {c['name']}")

    for svc in services:
        where = f"{label}: Service {svc['metadata']['name']}"
        ns = svc["metadata"].get("namespace", "")
        selector = svc["spec"].get("selector") or {}
        targets = [d for d in deployments if d["metadata"].get("namespace", "") == ns and
                   labels_match(selector, d["spec"]["template"]["metadata"].get("labels", {}))]
        if len(targets) != 1:
            fail(where, f"selector {selector} selects {len(targets)} Deployments, not one")
            continue
        c = targets[0]["spec"]["template"]["spec"]["containers"][0]
        ports = {p.get("name"): p["containerPort"] for p in c.get("ports", []) or []}
        for p in svc["spec"].get("ports", []):
            target = p.get("targetPort", p["port"])
            if target not in ports and target not in ports.values():
                fail(where, f"targetPort {target} is not a port of {c['name']}")
        binary = (c.get("command") or [None])[0]
        if binary == "picking-detector" and svc["spec"].get("clusterIP") != "None":
            fail(where, "the detector's Service must be headless (clusterIP: None): the "
                        "orchestrator's dns:/// round_robin needs every pod's address")

    for pdb in by_kind.get("PodDisruptionBudget", []):
        where = f"{label}: PodDisruptionBudget {pdb['metadata']['name']}"
        selector = (pdb["spec"].get("selector") or {}).get("matchLabels") or {}
        if not any(labels_match(selector, d["spec"]["template"]["metadata"].get("labels", {}))
                   for d in deployments):
            fail(where, f"selector {selector} selects no Deployment")

    names = {binary_of(d) for d in deployments}
    missing = {b for b in binaries if b.startswith("picking-")} - names
    if missing:
        fail(label, f"no Deployment runs {sorted(missing)}")


# --- rendering ------------------------------------------------------------------------------

def real_kustomize():
    """A kustomize v4+ command prefix, or None. Debian 12's kubectl (1.20) has kustomize v2."""
    if shutil.which("kustomize"):
        out = subprocess.run(["kustomize", "version"], capture_output=True, text=True)
        m = re.search(r"v(\d+)\.", out.stdout + out.stderr)
        if m and int(m.group(1)) >= 4:
            return ["kustomize", "build"]
    if shutil.which("kubectl"):
        out = subprocess.run(["kubectl", "version", "--client", "-o", "json"],
                             capture_output=True, text=True)
        try:
            version = json.loads(out.stdout).get("kustomizeVersion", "")
        except ValueError:
            version = ""
        m = re.match(r"v(\d+)\.", version)
        if m and int(m.group(1)) >= 4:
            return ["kubectl", "kustomize"]
    return None


def prepare_tree(source):
    """A copy of deploy/k8s to render, with stand-in certificate files for overlays/tls."""
    tmp = tempfile.mkdtemp(prefix="picking-k8s-")
    tree = os.path.join(tmp, "k8s")
    shutil.copytree(source, tree, ignore=shutil.ignore_patterns("__pycache__", "certs"))
    certs = os.path.join(tree, "overlays", "tls", "certs")
    os.makedirs(certs)
    for name in ["ca.pem"] + [f"{n}.{x}" for n in CERT_NAMES for x in ("pem", "key")]:
        with open(os.path.join(certs, name), "w", encoding="ascii") as f:
            f.write(f"stand-in {name}: scripts/make-certs.sh writes the real one\n")
    return tmp, tree


def run_checks(source, use_kustomize="auto", quiet=False):
    """All failures of the manifests under `source` (a deploy/k8s tree)."""
    fail = Failures()
    binaries = project_binaries()
    full_names = service_full_names()
    documented = documented_settings()
    kinds, definitions = load_schemas()
    checker = format_checker()
    kustomize = real_kustomize() if use_kustomize != "off" else None
    if use_kustomize == "require" and kustomize is None:
        fail("kustomize", "no kustomize v4+ found (kustomize or kubectl)")
    tmp, tree = prepare_tree(source)
    try:
        for target in TARGETS:
            directory = os.path.join(tree, target)
            try:
                objects = kustomize_lite.render(directory)
            except kustomize_lite.KustomizeError as e:
                fail(target, f"render: {e}")
                continue
            if kustomize:
                out = subprocess.run(kustomize + [directory], capture_output=True, text=True)
                if out.returncode != 0:
                    fail(target, f"{' '.join(kustomize)}: {out.stderr.strip()}")
                else:
                    real = [d for d in yaml.safe_load_all(out.stdout) if d is not None]
                    if real != objects:
                        key = lambda o: (o["kind"], o["metadata"]["name"])  # noqa: E731
                        a, b = {key(o): o for o in objects}, {key(o): o for o in real}
                        diff = sorted(set(a) ^ set(b)) or [k for k in a if a[k] != b.get(k)]
                        fail(target, f"kustomize_lite and {' '.join(kustomize)} render "
                                     f"differently: {diff[:5]}")
            if not quiet:
                kinds_count = {}
                for o in objects:
                    kinds_count[o["kind"]] = kinds_count.get(o["kind"], 0) + 1
                print(f"{target}: {len(objects)} objects "
                      f"({', '.join(f'{n} {k}' for k, n in sorted(kinds_count.items()))})")
            for o in objects:
                validate_schema(o, kinds, definitions, checker, fail,
                                f"{target}: {o['kind']} {o['metadata']['name']}")
            try:
                check_objects(objects, fail, target, binaries, full_names, documented)
            except (KeyError, TypeError, AttributeError, IndexError, ValueError) as e:
                # Objects malformed beyond what the checks read (the schema errors above
                # say where).
                fail(target, f"project checks stopped on a malformed object: "
                             f"{type(e).__name__} {e}")
    finally:
        shutil.rmtree(tmp)
    return fail.items, kustomize


# --- self-test ------------------------------------------------------------------------------

# (file under deploy/k8s, text, replacement, a fragment the failure must contain)
MUTATIONS = [
    ("base/detector.yaml", "readinessProbe:", "readinesProbe:", "'readinesProbe' was unexpected"),
    ("base/detector.yaml", "replicas: 3", 'replicas: "3"', "is not of type 'integer'"),
    ("base/planner.yaml", "memory: 1Gi}", "memory: 1GB}", "is not a 'quantity'"),
    ("base/scanner.yaml", "failureThreshold: 24", "failureThreshold: 3000000000",
     "is not a 'int32'"),
    ("base/planner.yaml", "grpc: {port: 50051, service:", "grpc: {port: 50052, service:",
     "must be grpc on port 50051"),
    ("base/robot.yaml", "grpc: {port: 50051}", "tcpSocket: {port: 50051}",
     "livenessProbe must be grpc"),
    ("base/gripper.yaml", "service: picking.gripper.v1.GripperService",
     "service: picking.gripper.v1.Gripper", "is not picking-gripper's service"),
    ("base/detector.yaml", "  clusterIP: None\n", "", "must be headless"),
    ("base/detector.yaml", "command: [picking-detector]", "command: [picking-detecter]",
     "not one of the project's"),
    ("base/config/detector.yaml", "preload: true", "pre_load: true",
     "setting 'pre_load' is not one of picking-detector's"),
    ("base/config/orchestrator.yaml", "endpoints: dns:///detector:50051",
     "endpoints: detector:50051", "must be dns:///SERVICE:50051"),
    ("base/config/orchestrator.yaml", "address: planner:50051", "address: planer:50051",
     "no Service 'planer'"),
    ("base/config/robot.yaml", "address: simulator:50051", "address: gripper:50051",
     "does not select a Deployment running picking-simulator"),
    ("base/robot.yaml", "  selector: {app.kubernetes.io/name: robot,",
     "  selector: {app.kubernetes.io/name: robots,", "selects 0 Deployments"),
    ("base/orchestrator.yaml", "terminationGracePeriodSeconds: 15",
     "terminationGracePeriodSeconds: 8", "leaves no margin"),
    ("base/orchestrator.yaml", "claimName: orchestrator-tasks", "claimName: tasks",
     "claim tasks missing"),
    ("base/simulator.yaml", "runAsNonRoot: true", "runAsNonRoot: false", "non-root uid"),
    ("base/config/simulator.yaml", "pick_layout_1.json", "pick_layout_9.json",
     "no such file in the image"),
    ("overlays/sim/task.yaml", "- orchestrator:50051", "- orchestrator:50050",
     "has no port 50050"),
    ("overlays/tls/tls-server.yaml", "value: --tls.ca=/etc/picking/tls/ca.crt",
     "value: --tls.ca=/etc/picking/tls/ca.pem", "--tls.ca /etc/picking/tls/ca.pem: not in a "
     "mounted Secret"),
    ("overlays/tls/kustomization.yaml", "{key: detector.crt, path: tls.crt}",
     "{key: orchestrator.crt, path: tls.crt}", "the certificate must name detector"),
    ("overlays/tls/tls-client.yaml", "  value: --tls-key\n", "  value: --tls-keyfile\n",
     "the command line needs"),
    ("overlays/tls/tcp-probes.yaml", "tcpSocket: {port: 50051}", "grpc: {port: 50051}",
     "the kubelet's gRPC probe has no TLS"),
    ("overlays/tls/kustomization.yaml", "namespace: picking\n", "",
     "Secret picking-tls missing"),
]


def self_test():
    failed = 0
    for i, (rel, old, new, expected) in enumerate(MUTATIONS, 1):
        tmp = tempfile.mkdtemp(prefix="picking-k8s-mutant-")
        tree = os.path.join(tmp, "k8s")
        shutil.copytree(K8S, tree, ignore=shutil.ignore_patterns("__pycache__", "certs"))
        try:
            path = os.path.join(tree, rel)
            with open(path, encoding="utf-8") as f:
                text = f.read()
            if old not in text:
                print(f"FAIL mutation {i}: '{old}' is no longer in {rel}: update the self-test")
                failed += 1
                continue
            with open(path, "w", encoding="utf-8") as f:
                f.write(text.replace(old, new, 1))
            failures, _ = run_checks(tree, use_kustomize="off", quiet=True)
            caught = [f for f in failures if expected in f]
            if caught:
                print(f"ok   mutation {i}: {rel}: {old.strip()!r} -> {new.strip()!r}: "
                      f"{caught[0]}")
            else:
                failed += 1
                print(f"FAIL mutation {i}: {rel}: {old.strip()!r} -> {new.strip()!r} was not "
                      f"caught as '{expected}'; failures: {failures[:3]}")
        finally:
            shutil.rmtree(tmp)
    print(f"{len(MUTATIONS) - failed} passed, {failed} failed")
    return 1 if failed else 0


def main(argv):
    mode = "auto"
    for a in argv[1:]:
        if a == "--self-test":
            return self_test()
        if a.startswith("--kustomize="):
            mode = a.split("=", 1)[1]
            if mode not in ("auto", "off", "require"):
                print("validate.py: --kustomize must be auto, off or require", file=sys.stderr)
                return 2
        else:
            print(__doc__, file=sys.stderr)
            return 2
    failures, kustomize = run_checks(K8S, use_kustomize=mode)
    print("cross-checked with " + " ".join(kustomize) if kustomize else
          "no kustomize v4+ here: rendered by kustomize_lite.py alone")
    for f in failures:
        print(f"FAIL {f}")
    if failures:
        print(f"{len(failures)} failures")
        return 1
    print("deploy/k8s: every overlay renders, matches the schemas and passes the checks")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
