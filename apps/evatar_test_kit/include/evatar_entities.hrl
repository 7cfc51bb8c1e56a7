%% The entities of the evatar suites that join pairings through the API
%% (evatar_test_entity): a VA with a light emulator and a temperature sink,
%% an Avatar with a light and a thermometer. Shared so that the suites
%% speak of the same bodies (apps/evatar_test_kit/README.md).
-define(E, evatar_test_entity).
-define(VA, <<"va1">>).
-define(AV, <<"7008">>).
-define(EMU, <<"LightEmulator01">>).
-define(SINK, <<"TemperatureSink">>).
-define(LIGHT, <<"HomeLightActuator01">>).
-define(THERMO, <<"Thermo01">>).
