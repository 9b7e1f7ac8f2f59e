// An independent OPC UA client (node-opcua, from the npm registry): browse fishfmu's folder, read a photo-eye,
// write a setpoint, call step(n) and stop(); prints "RESULT <json>" (node-opcua logs to stdout too).
const { OPCUAClient, AttributeIds, DataType, MessageSecurityMode, SecurityPolicy } = require("node-opcua-client");
(async () => {
  const client = OPCUAClient.create({ endpointMustExist: false, securityMode: MessageSecurityMode.None,
                                      securityPolicy: SecurityPolicy.None, connectionStrategy: { maxRetry: 20 } });
  await client.connect(process.argv[2]);
  const session = await client.createSession();
  const ns = (await session.readNamespaceArray()).indexOf("urn:fishfmu");
  const id = (name) => `ns=${ns};s=${name}`;
  const browsed = await session.browse(id("fishfmu"));
  const names = browsed.references.map((r) => r.browseName.name);
  const pe = await session.read({ nodeId: id("plant.pe_c4.blocked"), attributeId: AttributeIds.Value });
  const wrote = await session.write({ nodeId: id("drive_c4.speed_setpoint"), attributeId: AttributeIds.Value,
    value: { value: { dataType: DataType.Double, value: 1.25 } } });
  const stepped = await session.call({ objectId: id("fishfmu"), methodId: id("fishfmu.step"),
    inputArguments: [{ dataType: DataType.Int32, value: 100 }] });
  const speed = await session.read({ nodeId: id("drive_c4.belt_speed"), attributeId: AttributeIds.Value });
  const sent = await session.read({ nodeId: id("drive_c4.speed_setpoint"), attributeId: AttributeIds.Value });
  await session.call({ objectId: id("fishfmu"), methodId: id("fishfmu.stop"), inputArguments: [] });
  console.log("RESULT " + JSON.stringify({ names, pe: pe.value.value, peType: pe.value.dataType, write: wrote.name,
    time: stepped.outputArguments[0].value, speed: speed.value.value, sent: sent.value.value }));
  await session.close();
  await client.disconnect();
})().catch((e) => { console.error(String(e)); process.exit(1); });
