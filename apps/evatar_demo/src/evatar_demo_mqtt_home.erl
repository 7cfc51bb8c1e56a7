%% @doc The set-up of the simulated MQTT home (avatar_sim_mqtt_home, docs/mqtt.md
%% section 7) on a node that runs EVATAR: it creates the home's private
%% hardware pairing (between the simulated house and the devices' firmware
%% link, with fresh credentials), starts the home on it, and deletes the
%% pairing when the home stops. The simulator itself never drives the
%% mediator (docs/architecture.md section 1); scenarios and tests start the
%% home through here.
-module(evatar_demo_mqtt_home).

-export([start/1, stop/1]).

%% How long a stray pairing of the same id (left on another node of the
%% cluster by a start killed with its node) may take to go.
-define(STRAY_TIMEOUT, 30000).

%% @doc Creates the hardware pairing, then starts the home with it (the
%% options of avatar_sim_mqtt_home:start/1 but `hardware'). A pairing of that
%% id left by an earlier start is deleted first: the home deletes its own
%% when it stops, but not after a kill -9 of the node, when the durable
%% catalogue keeps it and the cluster restores it at every restart.
-spec start(map()) -> {ok, avatar_sim_mqtt_home:home()} | {error, term()}.
start(Opts) ->
    Id = avatar_sim_mqtt_home:hardware_pairing_id(avatar_sim_mqtt_home:entity_id(Opts)),
    Hardware = #{pairing => Id,
                 agent_credential => binary:encode_hex(crypto:strong_rand_bytes(16)),
                 avatar_credential => binary:encode_hex(crypto:strong_rand_bytes(16))},
    %% Long feedback timeout: the hardware's own answers may take simulated
    %% seconds; the VA's pairing has the timeout that matters. create_pairing,
    %% not ensure_pairing: the home's hardware link needs it running now.
    PairingOpts = #{agent_credential => maps:get(agent_credential, Hardware),
                    avatar_credential => maps:get(avatar_credential, Hardware),
                    feedback_timeout => 600000},
    _ = evatar:delete_pairing(Id),
    case create(Id, PairingOpts, erlang:monotonic_time(millisecond) + ?STRAY_TIMEOUT) of
        {ok, _} ->
            case avatar_sim_mqtt_home:start(Opts#{hardware => Hardware}) of
                {ok, Home} ->
                    {ok, Home};
                {error, _} = Error ->
                    _ = evatar:delete_pairing(Id),
                    Error
            end;
        {error, Why} ->
            {error, {hardware_pairing, Why}}
    end.

%% @doc Stops the home (its MQTT Avatar, devices and house), then deletes its
%% hardware pairing.
-spec stop(avatar_sim_mqtt_home:home()) -> ok.
stop(Home) ->
    #{hardware_pairing := Id} = avatar_sim_mqtt_home:info(Home),
    ok = avatar_sim_mqtt_home:stop(Home),
    _ = evatar:delete_pairing(Id),
    ok.

%% An instance of the old pairing on another node stops when that node
%% learns of the deletion (its catalogue, within a second): until then the
%% id exists.
create(Id, Opts, Deadline) ->
    case evatar:create_pairing(Id, Opts) of
        {error, already_exists} ->
            case erlang:monotonic_time(millisecond) < Deadline of
                true ->
                    timer:sleep(100),
                    _ = evatar:delete_pairing(Id),
                    create(Id, Opts, Deadline);
                false ->
                    {error, already_exists}
            end;
        Result ->
            Result
    end.
