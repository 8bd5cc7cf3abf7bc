#!/usr/bin/env node
// Extracts the JSON schemas of the Kubernetes kinds the manifests use, with every definition
// they reference, from the npm packages kubernetes-models@4.3.1 (Kubernetes 1.27.1) and
// @kubernetes-models/apimachinery@1.2.1, into one JSON file. Each module of those packages'
// _schemas/ folders registers one OpenAPI definition, converted to JSON Schema, with
// `register(id, schema)` from @kubernetes-models/validate; this script stands in for that
// package and collects what is registered. The schemas are written as the packages hold them;
// the test (deploy/k8s/validate.py) makes them strict when it loads them.
//
//   mkdir -p /tmp/km/node_modules/@kubernetes-models && cd /tmp/km
//   npm pack kubernetes-models@4.3.1 @kubernetes-models/apimachinery@1.2.1
//   tar xzf kubernetes-models-4.3.1.tgz && mv package node_modules/kubernetes-models
//   tar xzf kubernetes-models-apimachinery-1.2.1.tgz && mv package node_modules/@kubernetes-models/apimachinery
//   node /path/to/deploy/k8s/schemas/extract-schemas.js /tmp/km > kubernetes-1.27.1.json
"use strict";
const fs = require("fs");
const path = require("path");
const Module = require("module");

const root = path.resolve(process.argv[2] || ".");
const modules = path.join(root, "node_modules");

// The kinds of deploy/k8s (apiVersion, kind, the package module that defines it).
const kinds = [
  ["v1", "Namespace", "IoK8sApiCoreV1Namespace"],
  ["v1", "ConfigMap", "IoK8sApiCoreV1ConfigMap"],
  ["v1", "Secret", "IoK8sApiCoreV1Secret"],
  ["v1", "Service", "IoK8sApiCoreV1Service"],
  ["v1", "PersistentVolumeClaim", "IoK8sApiCoreV1PersistentVolumeClaim"],
  ["apps/v1", "Deployment", "IoK8sApiAppsV1Deployment"],
  ["batch/v1", "Job", "IoK8sApiBatchV1Job"],
  ["policy/v1", "PodDisruptionBudget", "IoK8sApiPolicyV1PodDisruptionBudget"],
];

const definitions = {};
const stub = {
  register(id, schema) {
    definitions[id] = schema;
  },
};
// Every require of @kubernetes-models/validate gets the collecting stub.
const originalLoad = Module._load;
Module._load = function (request, parent, isMain) {
  if (request === "@kubernetes-models/validate") return stub;
  return originalLoad.call(this, request, parent, isMain);
};

const kindIds = {};
for (const [apiVersion, kind, mod] of kinds) {
  const file = path.join(modules, "kubernetes-models", "_schemas", mod + ".js");
  require(file).addSchema();
  // The kind's own definition is the one whose apiVersion and kind enums match.
  const id = Object.keys(definitions).find((k) => {
    const p = definitions[k].properties || {};
    return (p.kind && (p.kind.enum || []).includes(kind) &&
            p.apiVersion && (p.apiVersion.enum || []).includes(apiVersion));
  });
  if (!id) throw new Error(`no definition of ${apiVersion} ${kind} in ${file}`);
  kindIds[`${apiVersion}/${kind}`] = id;
}

const pkg = (p) => JSON.parse(fs.readFileSync(path.join(modules, p, "package.json"), "utf8"));
const out = {
  source: {
    packages: [
      `kubernetes-models@${pkg("kubernetes-models").version}`,
      `@kubernetes-models/apimachinery@${pkg("@kubernetes-models/apimachinery").version}`,
    ],
    kubernetes: "1.27.1",
    license: "MIT (the packages; see LICENSE); the definitions come from the Kubernetes " +
             "OpenAPI specification (Apache-2.0)",
  },
  kinds: kindIds,
  definitions: Object.fromEntries(Object.keys(definitions).sort().map((k) => [k, definitions[k]])),
};
process.stdout.write(JSON.stringify(out, null, 1) + "\n");
