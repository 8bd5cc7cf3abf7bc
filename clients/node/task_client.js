#!/usr/bin/env node
// Example: run an APC task on the cell from Node.js, through the orchestrator.
//
// Starts the task of an APC 2016 task file (picking.orchestrator.v1.OrchestratorService/
// StartTask with the file's JSON text), streams its events (WatchTask) until the task ends,
// printing one line per event, then asks for the result (GetTask) and prints the score.
// The contracts are read from proto/ at run time (@grpc/proto-loader), so the client always
// matches the checkout it runs from.
//
//   node clients/node/task_client.js --address 127.0.0.1:50050 \
//       --task data/apc2016/tasks/pick_layout_1.json [--result outcome.json]
//
// Exit status: 0 when the task finished (TASK_STATE_SUCCEEDED), 1 when it failed, was
// cancelled or a call failed, 2 on bad usage.
'use strict';

const fs = require('fs');
const path = require('path');
const { parseArgs } = require('util');
const grpc = require('@grpc/grpc-js');
const protoLoader = require('@grpc/proto-loader');

const DEFAULT_PROTO_DIR = path.resolve(__dirname, '..', '..', 'proto');

function usage(message) {
  console.error(`task_client: ${message}`);
  console.error('usage: task_client.js --address HOST:PORT --task FILE [--result FILE] ' +
                '[--time-limit-s S] [--proto-dir DIR]');
  process.exit(2);
}

function parseCommandLine() {
  let values;
  try {
    ({ values } = parseArgs({
      options: {
        address: { type: 'string' },
        task: { type: 'string' },
        result: { type: 'string' },
        'time-limit-s': { type: 'string', default: '0' },
        'proto-dir': { type: 'string', default: process.env.PICKING_PROTO_DIR || DEFAULT_PROTO_DIR },
      },
    }));
  } catch (err) {
    usage(err.message);
  }
  if (!values.address) usage('--address is required');
  if (!values.task) usage('--task is required');
  const timeLimit = Number(values['time-limit-s']);
  if (!Number.isFinite(timeLimit) || timeLimit < 0) usage('--time-limit-s must be >= 0');
  return { ...values, timeLimit };
}

// The orchestrator's contract, loaded from the .proto files. Enums arrive as their names
// and 64-bit integers as strings (JavaScript numbers cannot hold every uint64).
function loadOrchestrator(protoDir) {
  const definition = protoLoader.loadSync('picking/orchestrator/v1/orchestrator.proto', {
    includeDirs: [protoDir],
    keepCase: true,
    longs: String,
    enums: String,
    defaults: true,
  });
  return grpc.loadPackageDefinition(definition).picking.orchestrator.v1;
}

// Turns a callback-style unary call into a promise.
function unary(client, method, request) {
  const deadline = new Date(Date.now() + 60 * 1000);
  return new Promise((resolve, reject) => {
    client[method](request, { deadline }, (err, reply) => (err ? reject(err) : resolve(reply)));
  });
}

function eventLine(e) {
  const step = e.step === 'STEP_UNSPECIFIED' ? '-' : e.step.replace(/^STEP_/, '');
  const state = e.state.replace(/^TASK_STATE_/, '');
  return `[${e.time_s.toFixed(1).padStart(7)} s] #${e.sequence} ${e.items_done}/${e.items_total} ` +
         `${e.item || '-'} ${step} ${e.step_ok ? 'ok' : 'FAIL'} ${state} ${e.message}`;
}

function eventRecord(e) {
  return {
    sequence: Number(e.sequence), time_s: e.time_s, item: e.item, step: e.step, ok: e.step_ok,
    message: e.message, items_done: e.items_done, items_total: e.items_total, state: e.state,
  };
}

// Streams the task's events until the stream ends; resolves to their records.
function watch(client, taskId) {
  return new Promise((resolve, reject) => {
    const events = [];
    const stream = client.WatchTask({ task_id: taskId });
    stream.on('data', (response) => {
      const event = response.event;
      console.log(eventLine(event));
      events.push(eventRecord(event));
    });
    stream.on('error', reject);
    stream.on('end', () => resolve(events));
  });
}

function summary(task, events) {
  const result = task.result || {};
  return {
    task_id: task.task_id, state: task.state, error: task.error, score: result.score,
    items_moved: result.items_moved, items_failed: result.items_failed,
    duration_s: result.duration_s, score_lines: result.score_lines || [],
    output: result.output_json ? JSON.parse(result.output_json) : null,
    output_file: result.output_file, events,
  };
}

async function main() {
  const args = parseCommandLine();
  let taskJson;
  try {
    taskJson = fs.readFileSync(args.task, 'utf8');
  } catch (err) {
    usage(`cannot read the task file: ${err.message}`);
  }
  const orchestrator = loadOrchestrator(args['proto-dir']);
  const client = new orchestrator.OrchestratorService(args.address,
                                                      grpc.credentials.createInsecure());
  try {
    const started = await unary(client, 'StartTask',
                                { task_json: taskJson, time_limit_s: args.timeLimit });
    console.log(`task ${started.task_id}`);
    const events = await watch(client, started.task_id);
    const task = await unary(client, 'GetTask', { task_id: started.task_id });
    const outcome = summary(task, events);
    if (args.result) fs.writeFileSync(args.result, JSON.stringify(outcome, null, 2) + '\n');
    console.log(`${outcome.state}: score ${outcome.score}, ${outcome.items_moved} moved, ` +
                `${outcome.items_failed} failed, ${outcome.duration_s.toFixed(0)} s task clock`);
    if (task.error) console.error(`error: ${task.error}`);
    return task.state === 'TASK_STATE_SUCCEEDED' ? 0 : 1;
  } catch (err) {
    const code = Object.keys(grpc.status).find((k) => grpc.status[k] === err.code) || err.code;
    console.error(`task_client: ${code}: ${err.details || err.message}`);
    return 1;
  } finally {
    client.close();
  }
}

main().then((status) => { process.exitCode = status; });
