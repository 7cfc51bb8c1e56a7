%% @doc Internal. The smart-home scenario with one house VA (paper, section
%% 3.2): the simulated easy smart home joins EVATAR as one gateway Avatar,
%% the house VA joins as its agent with the body of smart_home_va.xml, the
%% rules file gives the activities and the policies, and the people's
%% script brings the evening (and, by default, an intruder). The VA runs
%% the chosen policy (holiday by default) on the simulated clock. With
%% `mqtt', the house's devices are MQTT devices on mosquitto instead
%% (avatar_sim_mqtt_home), discovered and joined by an MQTT Avatar: the VA
%% is the same.
-module(evatar_demo_holiday).

-export([start/1, run_until/2, outcome/1, stop/1, run/1, default_script/0,
         start_datetime/0, login/1]).

-export_type([opts/0]).

%% `speed' and `tick' are the simulation clock's; `until' the local time
%% (HH:MM) at which run/1 stops; `spool' where the house writes e-mails and
%% photos; `rules' a rules file (the app's priv/home.rules by default);
%% `feedback_timeout' EVATAR's, in real ms; `print' narrates as it happens;
%% `mqtt' puts the devices on MQTT: `true' on a mosquitto of the scenario's
%% own (started and stopped with it), or a running broker's `#{host, port}'.
-type opts() :: #{speed => number(), tick => pos_integer(), seed => integer(),
                  start => calendar:datetime(), until => string(),
                  script => list(), spool => file:filename(), rules => file:filename(),
                  policy => binary(), feedback_timeout => pos_integer(),
                  print => boolean(), io => pid() | atom(),
                  mqtt => boolean() | #{host := inet:hostname() | inet:ip_address(),
                                        port := inet:port_number()}}.

-define(PAIRING, <<"home">>).
-define(VA_CRED, <<"home-va-secret">>).
-define(AV_CRED, <<"home-gateway-secret">>).
%% How long (real ms) the house's Avatars may take to describe every device
%% to EVATAR once started.
-define(DESCRIBED_TIMEOUT, 30000).

-spec start_datetime() -> calendar:datetime().
start_datetime() -> {{2024, 11, 15}, {17, 55, 0}}.

%% @doc Where a VA of one's own joins the house of a running scenario: the
%% scenario's listener, the pairing and the VAs' credential (a kept demo
%% prints them; docs/clients.md).
-spec login(evatar_demo_scenario:scenario()) ->
          #{endpoint := {inet:ip_address(), inet:port_number()}, pairing := binary(),
            credential := binary()}.
login(S) ->
    #{endpoint => evatar_demo_scenario:endpoint(S), pairing => ?PAIRING,
      credential => ?VA_CRED}.

%% @doc The holiday evening: nobody home; at 21:40 an intruder types a
%% wrong code at the door, comes into the hall, looks around, goes into the
%% living room and leaves.
-spec default_script() -> list().
default_script() ->
    [{{at, "21:40"}, <<"intruder">>, {keypad, <<"0000">>}},
     {{delay, 15000}, <<"intruder">>, {go, <<"hall">>}},
     {{delay, 60000}, <<"intruder">>, {go, <<"living">>}},
     {{delay, 90000}, <<"intruder">>, {go, <<"outside">>}}].

%% @doc Sets everything up and returns once the house VA is embodied, with
%% the simulated clock paused. The VA starts once EVATAR has every device of
%% the house from its Avatars; `{error, {not_described, Pairing, Missing}}'
%% if some are still missing after 30 s.
-spec start(opts()) -> {ok, evatar_demo_scenario:scenario()} | {error, term()}.
start(Opts) ->
    Start = maps:get(start, Opts, start_datetime()),
    %% Slow while the VA tests its body (devices answer at clock ticks),
    %% paused once it is embodied, at full speed in run_until/2.
    {ok, S0} = evatar_demo_scenario:start(
                 (maps:with([print, io], Opts))#{name => holiday,
                                                 clock => #{speed => 2, start => Start,
                                                            tick => maps:get(tick, Opts, 500)}}),
    Clock = evatar_demo_scenario:get(clock, S0),
    RulesFile = maps:get(rules, Opts, filename:join(evatar_demo_scenario:priv_dir(),
                                                     "home.rules")),
    case reference_agents:parse_rules(RulesFile) of
        {ok, Rules} ->
            start(Opts, Clock, Rules, RulesFile, S0);
        {error, Reason} ->
            ok = evatar_demo_scenario:stop(S0),
            {error, {rules, reference_agents:rules_error(RulesFile, Reason)}}
    end.

start(Opts, Clock, Rules, RulesFile, S0) ->
    Policy = maps:get(policy, Opts, <<"holiday">>),
    S1 = evatar_demo_scenario:pairing(
           ?PAIRING, #{agent_credential => ?VA_CRED, avatar_credential => ?AV_CRED,
                       feedback_timeout => maps:get(feedback_timeout, Opts, 5000)}, S0),
    Spool = maps:get(spool, Opts, "spool"),
    HomeOpts = #{clock => Clock, seed => maps:get(seed, Opts, 1),
                 endpoints => [evatar_demo_scenario:endpoint(S1)],
                 spool => Spool, script => maps:get(script, Opts, default_script())},
    case start_home(maps:get(mqtt, Opts, false), HomeOpts, S1) of
        {ok, S2, Joined} ->
            evatar_demo_scenario:say(S2, info,
                                     io_lib:format("~srules from ~s; policy ~s; spool ~s",
                                                   [Joined, RulesFile, Policy,
                                                    filename:absname(Spool)])),
            await_house(Opts, Rules, Policy, S2);
        {error, Why, S2} ->
            ok = evatar_demo_scenario:stop(S2),
            {error, Why}
    end.

%% The VA starts once EVATAR has every device of the house from its Avatars
%% (over MQTT: the MQTT Avatar's and the notifier's descriptions registered,
%% not only their connections made), so its first embodiment test is of the
%% whole house.
await_house(Opts, Rules, Policy, S2) ->
    #{components := Cs} = evatar_demo_scenario:body("smart_home.xml"),
    case evatar_demo_scenario:await_described(?PAIRING, [Id || #{id := Id} <- Cs],
                                              ?DESCRIBED_TIMEOUT) of
        ok ->
            start_va(Opts, Rules, Policy, S2);
        {error, _} = E ->
            ok = evatar_demo_scenario:stop(S2),
            E
    end.

start_va(Opts, Rules, Policy, S2) ->
    Clock = evatar_demo_scenario:get(clock, S2),
    Body = (evatar_demo_scenario:body("smart_home_va.xml"))#{entity_id := <<"house-va">>},
    Seen = atomics:new(1, [{signed, true}]),
    {Va, S3} = evatar_demo_scenario:start_va(
                 #{name => <<"house-va">>, mind => reference_agents_home,
                   mind_args => #{body => Body, rules => Rules, policy => Policy},
                   body => Body, pairing => ?PAIRING, credential => ?VA_CRED, seen => Seen}, S2),
    S4 = evatar_demo_scenario:add(va, Va, S3),
    case evatar_demo_scenario:await_va_state(Va, [embodied], 20000, house_va_embodied) of
        {ok, _} ->
            ok = avatar_sim:pause(Clock),
            ok = avatar_sim:set_speed(Clock, maps:get(speed, Opts, 1000)),
            {ok, pace(maps:get(mqtt, Opts, false), S4, Seen)};
        {error, _} = E -> ok = evatar_demo_scenario:stop(S4), E
    end.

%% Over TCP the scenario counts every signal of the house and the VA, and
%% runs them in lockstep; over MQTT the broker's traffic is out of its
%% sight, and the clock follows the VA (evatar_demo_scenario:follow/2).
pace(false, S, Seen) -> evatar_demo_scenario:lockstep(S, Seen);
pace(_Mqtt, S, Seen) -> evatar_demo_scenario:follow(S, Seen).

%% The house over TCP: one gateway Avatar with every device.
start_home(false, HomeOpts, S1) ->
    {ok, Home} = avatar_sim:start_home(HomeOpts#{gateways => [#{pairing => ?PAIRING,
                                                                credential => ?AV_CRED}]}),
    S2 = evatar_demo_scenario:add(home, Home,
                                  evatar_demo_scenario:add(avatars, [Home], S1)),
    {ok, S2, ["the easy smart home joined pairing ", ?PAIRING, "; "]};
%% The house over MQTT, on a broker of the scenario's own.
start_home(true, HomeOpts, S1) ->
    case evatar_demo_broker:start_link(#{}) of
        {ok, Broker} ->
            S2 = evatar_demo_scenario:on_stop(
                   fun() -> evatar_demo_broker:stop(Broker) end,
                   evatar_demo_scenario:add(broker, Broker, S1)),
            start_home(evatar_demo_broker:address(Broker), HomeOpts, S2);
        {error, Message} ->
            {error, {broker, Message}, S1}
    end;
start_home(#{host := _, port := _} = Mqtt, HomeOpts, S1) ->
    case evatar_demo_mqtt_home:start(HomeOpts#{mqtt => Mqtt, pairing => ?PAIRING,
                                               credential => ?AV_CRED}) of
        {ok, MqttHome} ->
            S2 = evatar_demo_scenario:on_stop(
                   fun() -> evatar_demo_mqtt_home:stop(MqttHome) end,
                   evatar_demo_scenario:add(mqtt, Mqtt, S1)),
            House = avatar_sim_mqtt_home:house(MqttHome),
            S3 = evatar_demo_scenario:add(mqtt_home, MqttHome,
                                          evatar_demo_scenario:add(home, House, S2)),
            evatar_demo_scenario:say(S3, info, mqtt_story(Mqtt, MqttHome)),
            {ok, S3, ""};
        {error, Why} ->
            {error, {mqtt_home, Why}, S1}
    end.

%% Where the devices are and what the MQTT Avatar made of them.
mqtt_story(#{host := Host, port := Port}, MqttHome) ->
    #{devices := Devices, entity := Entity} = avatar_sim_mqtt_home:info(MqttHome),
    #{components := Discovered} = mqtt_avatar:description(avatar_sim_mqtt_home:avatar(MqttHome)),
    io_lib:format("the easy smart home's ~b devices are on mosquitto at ~s:~b; the MQTT Avatar ~s "
                  "discovered ~b of them through Home Assistant discovery (~s) and joined "
                  "pairing ~s; the notifier (a PC) joined over TCP",
                  [length(Devices), host(Host), Port, Entity, length(Discovered),
                   lists:join(", ", [Id || #{id := Id} <- Discovered]), ?PAIRING]).

host(Host) when is_tuple(Host) -> inet:ntoa(Host);
host(Host) -> Host.

%% @doc Lets simulated time run until the house's clock shows `HHMM' (on
%% the start day, or the next day if that time has passed), then pauses.
%% Over TCP the clock runs in lockstep with the VAs and the house
%% (evatar_demo_scenario:lockstep/2), so what happened by then is the same
%% however slow the machine; over MQTT it never runs more than two simulated
%% minutes ahead of what the VA it follows has perceived
%% (evatar_demo_scenario:follow/2). It returns once the VAs have caught up
%% (settle/1).
-spec run_until(evatar_demo_scenario:scenario(), string()) -> ok | {error, term()}.
run_until(S, HHMM) ->
    Clock = evatar_demo_scenario:get(clock, S),
    Target = target_ms(avatar_sim:now(Clock), HHMM),
    ok = avatar_sim:resume(Clock),
    R = evatar_demo_scenario:await(end_ok(Clock, Target), 600000, {clock, HHMM}),
    ok = avatar_sim:pause(Clock),
    case R of
        {ok, _} -> evatar_demo_scenario:settle(S);
        Error -> Error
    end.

end_ok(Clock, Target) ->
    fun() ->
            case avatar_sim:now(Clock) >= Target of
                true -> {true, ok};
                false -> false
            end
    end.

target_ms(NowMs, HHMM) ->
    Minute = reference_agents:minute_of_day(list_to_binary(HHMM)),
    {Date, _} = calendar:system_time_to_universal_time(NowMs, millisecond),
    Day = (calendar:datetime_to_gregorian_seconds({Date, {0, 0, 0}})
           - calendar:datetime_to_gregorian_seconds({{1970, 1, 1}, {0, 0, 0}})) * 1000,
    T = Day + Minute * 60000,
    case T > NowMs of
        true -> T;
        false -> T + 86400000
    end.

%% @doc What happened: the VA's view (activities, decisions, outcomes,
%% e-mails), the house's (lights, e-mails, photos, sounds) and the story;
%% over MQTT also the broker (`mqtt': host and port) and the MQTT Avatar's
%% view (`mqtt_avatar': its status and problems).
-spec outcome(evatar_demo_scenario:scenario()) -> map().
outcome(S) ->
    Va = evatar_demo_scenario:get(va, S),
    Home = evatar_demo_scenario:get(home, S),
    Outcome = #{va => reference_agents:inspect(Va),
                home => avatar_sim:state(Home),
                story => reference_agents_narrator:events(evatar_demo_scenario:narrator(S))},
    case mqtt_home(S) of
        none ->
            Outcome;
        MqttHome ->
            A = avatar_sim_mqtt_home:avatar(MqttHome),
            Outcome#{mqtt => evatar_demo_scenario:get(mqtt, S),
                     mqtt_avatar => #{status => mqtt_avatar:status(A),
                                      problems => mqtt_avatar:problems(A)}}
    end.

mqtt_home(S) ->
    try evatar_demo_scenario:get(mqtt_home, S)
    catch error:{badkey, _} -> none
    end.

-spec stop(evatar_demo_scenario:scenario()) -> ok.
stop(S) -> evatar_demo_scenario:stop(S).

%% @doc Start, run until `until' (22:05 by default), outcome, stop.
-spec run(opts()) -> {ok, map()} | {error, term()}.
run(Opts) ->
    case start(Opts) of
        {ok, S} ->
            try
                ok = run_until(S, maps:get(until, Opts, "22:05")),
                {ok, outcome(S)}
            after
                stop(S)
            end;
        {error, _} = E -> E
    end.
