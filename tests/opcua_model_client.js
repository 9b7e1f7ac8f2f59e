// An independent OPC UA client (node-opcua): browse fishfmu's information model as an integrator's tool does, read
// units and ranges with node-opcua's own helper (readUAAnalogItem), the states of a Boolean and an enumeration, the
// server's BuildInfo; as an anonymous client it is refused a write, then as the user given (argv 3 and 4) it writes and
// stops the run; prints "RESULT <json>" (node-opcua logs to stdout too).
const { OPCUAClient, AttributeIds, BrowseDirection, DataType, NodeClass, MessageSecurityMode, SecurityPolicy,
        UserTokenType, readUAAnalogItem, makeBrowsePath } = require("node-opcua-client");
// node-opcua gives an Int64 as [high, low] 32-bit words
const int64 = (v) => Array.isArray(v) ? Number(BigInt.asIntN(64, (BigInt(v[0] >>> 0) << 32n) | BigInt(v[1] >>> 0)))
                                      : Number(v);
(async () => {
  const client = OPCUAClient.create({ endpointMustExist: false, securityMode: MessageSecurityMode.None,
                                      securityPolicy: SecurityPolicy.None, connectionStrategy: { maxRetry: 20 } });
  await client.connect(process.argv[2]);
  const session = await client.createSession();
  const ns = (await session.readNamespaceArray()).indexOf("urn:fishfmu");
  const id = (name) => `ns=${ns};s=${name}`;
  // every object under the root (their paths), and every variable and method held by an object
  const objects = {}, leaves = [];
  const walk = async (nodeId, path) => {
    objects[path] = nodeId;
    const r = await session.browse({ nodeId, browseDirection: BrowseDirection.Forward, includeSubtypes: true,
      referenceTypeId: "HierarchicalReferences", resultMask: 63 });
    for (const ref of r.references) {
      const p = `${path}/${ref.browseName.name}`;
      if (ref.nodeClass === NodeClass.Object) await walk(ref.nodeId.toString(), p);
      else leaves.push({ path: p, nodeId: ref.nodeId.toString(), nodeClass: NodeClass[ref.nodeClass],
                         typeDefinition: ref.typeDefinition.toString() });
    }
  };
  await walk(id("fishfmu"), "Objects/fishfmu");
  const vars = leaves.filter((l) => l.nodeClass === "Variable");
  // AccessLevel: what the node allows; UserAccessLevel: what this (anonymous, read-only) session may do
  const attrs = await session.read(vars.flatMap((v) => [
    { nodeId: v.nodeId, attributeId: AttributeIds.AccessLevel },
    { nodeId: v.nodeId, attributeId: AttributeIds.UserAccessLevel },
    { nodeId: v.nodeId, attributeId: AttributeIds.Description },
    { nodeId: v.nodeId, attributeId: AttributeIds.DataType }]));
  vars.forEach((v, i) => {
    v.writable = (attrs[4 * i].value.value & 2) !== 0;
    v.userWritable = (attrs[4 * i + 1].value.value & 2) !== 0;
    v.description = attrs[4 * i + 2].value.value.text;
    v.dataType = attrs[4 * i + 3].value.value.toString();
  });
  const analog = {};
  for (const name of ["plant.cam.lead_x", "plant.c4.load_force", "drive_c4.speed_setpoint"]) {
    const a = await readUAAnalogItem(session, id(name));
    analog[name] = { unit: a.engineeringUnits && a.engineeringUnits.displayName.text,
                     unitId: a.engineeringUnits && a.engineeringUnits.unitId,
                     namespaceUri: a.engineeringUnits && a.engineeringUnits.namespaceUri,
                     range: a.engineeringUnitsRange && [a.engineeringUnitsRange.low, a.engineeringUnitsRange.high] };
  }
  const prop = async (name, property) => {
    const t = await session.translateBrowsePath(makeBrowsePath(id(name), `.${property}`));
    if (!t.statusCode.isGood()) return null;
    return (await session.read({ nodeId: t.targets[0].targetId, attributeId: AttributeIds.Value })).value.value;
  };
  const trueState = await prop("plant.pe_c4.blocked", "TrueState");
  const falseState = await prop("plant.pe_c4.blocked", "FalseState");
  const enumValues = (await prop("plant.cam.lead_heading", "EnumValues")) || [];
  const asText = await prop("plant.cam.lead_heading", "ValueAsText");
  const build = (await session.read({ nodeId: "i=2260", attributeId: AttributeIds.Value })).value.value;
  const gate = { nodeId: id("plant.gate.command"), attributeId: AttributeIds.Value,
                 value: { value: { dataType: DataType.Boolean, value: true } } };
  const stop = { objectId: id("fishfmu"), methodId: id("fishfmu.stop"), inputArguments: [] };
  // a refused request is a service fault: node-opcua rejects the promise with the status in its message
  const status = async (p) => {
    try { const r = await p; return (r.statusCode || r).name; } catch (e) { return (/Bad\w+/.exec(String(e)) || [String(e)])[0]; }
  };
  const anonymous = { write: await status(session.write(gate)), stop: await status(session.call(stop)) };
  const operator = await client.createSession({ type: UserTokenType.UserName, userName: process.argv[3],
                                                password: process.argv[4] });
  const userLevel = (await operator.read({ nodeId: id("plant.gate.command"),
                                          attributeId: AttributeIds.UserAccessLevel })).value.value;
  const byUser = { userWritable: (userLevel & 2) !== 0, write: await status(operator.write(gate)),
                   stop: await status(operator.call(stop)) };
  console.log("RESULT " + JSON.stringify({ ns, objects: Object.keys(objects), leaves, analog,
    twoStates: [trueState && trueState.text, falseState && falseState.text],
    enumValues: enumValues.map((e) => [int64(e.value), e.displayName.text]), asText: asText && asText.text,
    build: { productName: build.productName, manufacturerName: build.manufacturerName,
             softwareVersion: build.softwareVersion }, anonymous, byUser }));
  await client.disconnect();
})().catch((e) => { console.error(String(e && e.stack || e)); process.exit(1); });
