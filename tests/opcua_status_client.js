// An independent OPC UA client (node-opcua) as a PLC follows the run: subscribe to the root object's events, start
// a line waiting for it, pause, resume, change the speed, wait for "finished", read the KPIs and the clock, then
// stay connected until the server goes (after its grace time); prints "RESULT <json>".
const { OPCUAClient, AttributeIds, DataType, MessageSecurityMode, SecurityPolicy, TimestampsToReturn,
        constructEventFilter } = require("node-opcua-client");
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
(async () => {
  const client = OPCUAClient.create({ endpointMustExist: false, securityMode: MessageSecurityMode.None,
                                      securityPolicy: SecurityPolicy.None,
                                      connectionStrategy: { maxRetry: 0 } });
  let lost = false;
  client.on("connection_lost", () => { lost = true; });
  client.on("close", () => { lost = true; });
  await client.connect(process.argv[2]);
  const session = await client.createSession();
  const ns = (await session.readNamespaceArray()).indexOf("urn:fishfmu");
  const id = (name) => `ns=${ns};s=${name}`;
  const read = async (name) => (await session.read({ nodeId: id(name), attributeId: AttributeIds.Value })).value.value;
  const call = async (name, args = []) => (await session.call({ objectId: id("fishfmu"), methodId: id(`fishfmu.${name}`),
                                                                 inputArguments: args })).statusCode.name;
  const subscription = await session.createSubscription2({ requestedPublishingInterval: 20, publishingEnabled: true,
    requestedMaxKeepAliveCount: 10, requestedLifetimeCount: 100, maxNotificationsPerPublish: 100, priority: 1 });
  const events = [];
  const monitored = await subscription.monitor({ nodeId: id("fishfmu"), attributeId: AttributeIds.EventNotifier },
    { samplingInterval: 0, queueSize: 100, filter: constructEventFilter(["Message", "SourceName"]) },
    TimestampsToReturn.Both);
  monitored.on("changed", (fields) => events.push(fields[0].value.text));
  const calls = {};
  const waiting = await read("fishfmu.run_state");
  await sleep(500);
  const timeWaiting = await read("fishfmu.time_s");
  calls.stepInRealTime = await call("step", [{ dataType: DataType.Int32, value: 1 }]);
  calls.resumeWhileWaiting = await call("resume");
  calls.start = await call("start");
  await sleep(300);
  calls.pause = await call("pause");
  const tPaused = await read("fishfmu.time_s");
  await sleep(500);
  const tStillPaused = await read("fishfmu.time_s");
  calls.resume = await call("resume");
  calls.setSpeed = await call("set_speed", [{ dataType: DataType.Double, value: 4.0 }]);
  calls.setSpeedTooFast = await call("set_speed", [{ dataType: DataType.Double, value: 1e6 }]);
  const factor = await read("fishfmu.realtime_factor");
  let state;
  while ((state = await read("fishfmu.run_state")) === "running") await sleep(50);
  const kpis = { fish_in: await read("fishfmu.kpis.fish_in"), lost: await read("fishfmu.kpis.lost") };
  const clock = { time: await read("fishfmu.time_s"), lateSteps: await read("fishfmu.late_steps"),
                  lagMax: await read("fishfmu.lag_max_s"), reached: await read("fishfmu.realtime_factor_reached") };
  await sleep(300);
  const eventsAtEnd = [...events];
  const before = Date.now();
  while (!lost && Date.now() - before < 60000) await sleep(100);
  console.log("RESULT " + JSON.stringify({ waiting, timeWaiting, calls, tPaused, tStillPaused, factor, state, kpis,
    clock, eventsAtEnd, lost }));
  process.exit(0);
})().catch((e) => { console.error(String(e && e.stack || e)); process.exit(1); });
