%% @doc Test support. One entity of a pairing (a VA or an Avatar) driving
%% traffic through an HA client of the bridge (agent_bridge_client with
%% several endpoints), and recording its history for evatar_test_checker: every
%% signal it sent, every one the bridge told it was accepted (`Ack'), and
%% every one it received, with epochs and reconnections.
%% Part of the cluster harness (evatar_test_cluster).
%%
%% The VA sends a request awaiting feedback every `request_interval' ms; the
%% Avatar answers every request with a feedback (SignalID "fb-" ++ the
%% request's) and sends sensor data every `sensor_interval' ms. SignalIDs
%% are unique per pairing, so the checker can tell a duplicate from a new
%% signal.
%%
%% ```
%%  connecting --connected, described--> running --stop_traffic--> quiet
%% '''
-module(evatar_test_traffic).
-behaviour(gen_server).

-export([start_pair/3, start_entity/1, pairing_opts/0, stop_traffic/1, burst/2, dump/2, settle/2, settle/3, settle_accepted/2,
         history/1, close/1,
         status/1, await_bound/2, round_trip/2, va_description/1, avatar_description/1,
         since/2, carried/3, queued/2]).
-export([init/1, handle_continue/2, handle_call/3, handle_cast/2, handle_info/2,
         terminate/2]).

-export_type([pair/0, history/0]).

-type pair() :: #{va := pid(), av := pid(), pairing := binary()}.
%% sent: SignalIDs in send order; accepted: in Ack order; received: the
%% SignalIDs of signals received from the other entity, in arrival order,
%% each with the epoch it carried; mediator: signals from EVATAR itself
%% (errors, timeouts); reconnects: the client's {reconnected, Info} maps;
%% closed: the client's close reason, if it gave up; sent_at, accepted_at:
%% when each signal was handed to the client and first acknowledged;
%% received_at: when each signal from the other entity arrived, every time
%% (monotonic ms of this node).
-type history() :: #{entity := binary(), role := agent | avatar,
                     sent := [binary()], sent_at := #{binary() => integer()},
                     accepted_at := #{binary() => integer()},
                     received_at := #{binary() => [integer()]},
                     accepted := [binary()],
                     received := [{binary(), integer() | undefined}],
                     mediator := [map()], reconnects := [map()],
                     closed := term()}.

-define(CRED_VA, <<"va-secret">>).
-define(CRED_AV, <<"avatar-secret">>).

-record(s, {role :: agent | avatar,
            pairing :: binary(),
            entity :: binary(),
            endpoints :: list(),
            opts :: map(),
            client :: pid() | undefined,
            running = true :: boolean(),
            bound = false :: boolean(),
            counter = 0 :: non_neg_integer(),
            sent = [] :: [binary()],
            sent_at = #{} :: #{binary() => integer()},
            accepted_at = #{} :: #{binary() => integer()},
            received_at = #{} :: #{binary() => [integer()]},
            accepted = [] :: [binary()],
            received = [] :: [{binary(), term()}],
            mediator = [] :: [map()],
            reconnects = [] :: [map()],
            closed = undefined :: term(),
            waiters = [] :: [{binary(), gen_server:from()}]}).

%% ---------------------------------------------------------------------------
%% API
%% ---------------------------------------------------------------------------

%% @doc Starts a VA and an Avatar of pairing Id (created with
%% pairing_opts/0), both connected to Endpoints, described, and bound.
%% Opts: request_interval, sensor_interval (ms, or off; default off),
%% client (extra agent_bridge_client options), bound_timeout, owner (the
%% entities stop when it exits; default the caller), notify (a pid told
%% `{evatar_test_traffic, Entity, {received, SignalID, Epoch, MonotonicUs}}' of every
%% signal received from the other entity).
-spec start_pair([{inet:ip_address(), inet:port_number()}], binary(), map()) ->
          {ok, pair()} | {error, term()}.
start_pair(Endpoints, Id, Opts) ->
    Common = #{pairing => Id, endpoints => Endpoints, opts => Opts,
               owner => maps:get(owner, Opts, self())},
    {ok, Av} = start_entity(Common#{role => avatar, entity => <<Id/binary, "-av">>}),
    {ok, Va} = start_entity(Common#{role => agent, entity => <<Id/binary, "-va">>}),
    Pair = #{va => Va, av => Av, pairing => Id},
    Timeout = maps:get(bound_timeout, Opts, 60000),
    case {await_bound(Va, Timeout), await_bound(Av, Timeout)} of
        {ok, ok} -> {ok, Pair};
        Other -> close(Pair), {error, {not_bound, Id, Other}}
    end.

%% @doc Starts one entity, not linked; it stops when its `owner' exits.
-spec start_entity(map()) -> {ok, pid()}.
start_entity(Args) ->
    gen_server:start(?MODULE, Args, []).

%% @doc The options of a pairing these entities can join: their
%% credentials, and a feedback timeout longer than any failover of the
%% tests (a Timeout feedback would hide a lost feedback).
-spec pairing_opts() -> evatar:pairing_opts().
pairing_opts() ->
    #{agent_credential => ?CRED_VA, avatar_credential => ?CRED_AV,
      join_timeout => 30000, feedback_timeout => 120000}.

%% @doc Sends nothing new from now on (answers to requests still go out).
-spec stop_traffic(pair()) -> ok.
stop_traffic(#{va := Va, av := Av}) ->
    %% An entity may be waiting for room in its client's window.
    ok = gen_server:call(Va, stop_traffic, 120000),
    ok = gen_server:call(Av, stop_traffic, 120000).

%% @doc Waits until both clients have every sent signal acknowledged and
%% every signal the other accepted has arrived; `{error, ...}' after
%% Timeout ms (the checker then says what is missing).
-spec settle(pair(), pos_integer()) -> ok | {error, term()}.
settle(Pair, Timeout) ->
    settle(Pair, [], Timeout).

%% @doc As settle/2 for a run with power cuts at `Cuts' (as for
%% evatar_test_checker:check_pairs/2): waits for every accepted signal to arrive
%% except those the checker counts as in flight at a cut, which never do
%% (docs/ha.md section 6). Reading the histories once the Acks are in
%% would race the deliveries still under way (a feedback acknowledged to
%% the Avatar a moment before the read, not yet at the VA) and count them
%% lost.
-spec settle(pair(), [integer()], pos_integer()) -> ok | {error, term()}.
settle(#{va := Va, av := Av} = Pair, Cuts, Timeout) ->
    evatar_test_cluster:await(
      fun() ->
              %% histories/1 reads the VA, then the Avatar: a signal the
              %% Avatar's read shows accepted counts as arrived only if the
              %% earlier read of the VA had it already.
              #{va := HVa, av := HAv} = H = histories(Pair),
              acked(HVa) andalso acked(HAv)
                  andalso maps:get(lost, evatar_test_checker:check_pairs([H], Cuts)) =:= []
                  andalso is_process_alive(Va) andalso is_process_alive(Av)
      end, Timeout, {settle, maps:get(pairing, Pair)}).

%% @doc Waits only until both clients have every sent signal acknowledged
%% (their resends see to it after any failover). For a two-node partition,
%% where signals the cut-off active accepted may be lost by design
%% (docs/ha.md), so waiting for them all to arrive could wait for ever;
%% the checker then reports them.
-spec settle_accepted(pair(), pos_integer()) -> ok | {error, term()}.
settle_accepted(#{va := Va, av := Av} = Pair, Timeout) ->
    evatar_test_cluster:await(
      fun() ->
              #{va := HVa, av := HAv} = histories(Pair),
              acked(HVa) andalso acked(HAv)
                  andalso is_process_alive(Va) andalso is_process_alive(Av)
      end, Timeout, {settle_accepted, maps:get(pairing, Pair)}).

acked(#{sent := Sent, accepted := Acc}) ->
    ordsets:subtract(ordsets:from_list(Sent), ordsets:from_list(Acc)) =:= [].

%% @doc Both entities' histories.
-spec history(pair()) -> #{va := history(), av := history()}.
history(Pair) -> histories(Pair).

histories(#{va := Va, av := Av}) ->
    #{va => gen_server:call(Va, history, 30000), av => gen_server:call(Av, history, 30000)}.

%% @doc What each entity of a pair did since the monotonic instant Since
%% (ms of this node): how many signals it received from the other entity
%% (each arrival counted), and how many it sent that no node acknowledged.
-spec since(pair(), integer()) ->
          #{va := #{received := non_neg_integer(), unacked := non_neg_integer()},
            av := #{received := non_neg_integer(), unacked := non_neg_integer()}}.
since(#{va := Va, av := Av}, Since) ->
    #{va => gen_server:call(Va, {since, Since}, 30000), av => gen_server:call(Av, {since, Since}, 30000)}.

%% @doc A probe for evatar_test_wait: every VA and every Avatar of Pairs
%% received at least N signals since Since (the pairings carry traffic
%% both ways); else {false, the counts}.
-spec carried([pair()], integer(), non_neg_integer()) -> true | {false, [non_neg_integer()]}.
carried(Pairs, Since, N) ->
    Counts = [R || P <- Pairs, #{received := R} <- maps:values(since(P, Since))],
    lists:all(fun(K) -> K >= N end, Counts) orelse {false, Counts}.

%% @doc A probe for evatar_test_wait: every VA and every Avatar of Pairs
%% holds a signal sent since Since that no node acknowledged (the clients
%% queue while no node serves them); else {false, the counts}.
-spec queued([pair()], integer()) -> true | {false, [non_neg_integer()]}.
queued(Pairs, Since) ->
    Counts = [U || P <- Pairs, #{unacked := U} <- maps:values(since(P, Since))],
    lists:all(fun(K) -> K > 0 end, Counts) orelse {false, Counts}.

%% @doc The Avatar entity sends N sensor signals at once (for throughput).
-spec burst(pid(), pos_integer()) -> ok.
burst(Avatar, N) -> gen_server:call(Avatar, {burst, N}, 120000).

%% @doc Writes a pair's history as Erlang terms in a file of the current
%% directory (a CT case's log directory) for a person to read when a check
%% fails; returns the file name.
-spec dump(pair(), #{va := history(), av := history()}) -> file:filename().
dump(#{pairing := Id}, History) ->
    File = filename:absname(binary_to_list(Id) ++ ".history"),
    ok = file:write_file(File, io_lib:format("~p.~n", [History])),
    File.

%% @doc The client's status (agent_bridge_client:status/1) of one entity.
-spec status(pid()) -> map().
status(Entity) -> gen_server:call(Entity, status, 30000).

%% @doc Says Bye with both clients and stops both entities.
-spec close(pair()) -> ok.
close(#{va := Va, av := Av}) ->
    _ = [catch gen_server:stop(P, normal, 10000) || P <- [Va, Av]],
    ok.

-spec await_bound(pid(), pos_integer()) -> ok | {error, term()}.
await_bound(Entity, Timeout) ->
    try gen_server:call(Entity, await_bound, Timeout)
    catch exit:{timeout, _} -> {error, bound_timeout};
          exit:{Reason, _} -> {error, Reason}
    end.

%% @doc One more request from the VA, waiting (up to Timeout ms) for its
%% feedback to arrive: a signal through whichever instance is active now.
%% Returns the epoch the feedback carried.
-spec round_trip(pair(), pos_integer()) -> {ok, integer()} | {error, term()}.
round_trip(#{va := Va}, Timeout) ->
    try gen_server:call(Va, {round_trip, Timeout}, Timeout + 1000)
    catch exit:{timeout, _} -> {error, timeout}
    end.

%% ---------------------------------------------------------------------------
%% gen_server
%% ---------------------------------------------------------------------------

-spec init(map()) -> {ok, #s{}, {continue, connect}}.
init(#{role := Role, pairing := Id, entity := Entity, endpoints := Eps, opts := Opts,
       owner := Owner}) ->
    _ = erlang:monitor(process, Owner),
    {ok, #s{role = Role, pairing = Id, entity = Entity, endpoints = Eps, opts = Opts},
     {continue, connect}}.

-spec handle_continue(connect, #s{}) -> {noreply, #s{}} | {stop, term(), #s{}}.
handle_continue(connect, #s{role = Role, pairing = Id, entity = Entity} = S) ->
    ClientOpts = maps:merge(#{pairing => Id, role => Role, entity_id => Entity,
                              credential => credential(Role), ha => true,
                              handshake_timeout => 1000, reconnect_backoff => {20, 500},
                              reconnect_limit => 120000, notify_acks => true,
                              owner => self()},
                            maps:get(client, S#s.opts, #{})),
    case connect(S#s.endpoints, ClientOpts, 20) of
        {ok, Client} ->
            Description = case Role of
                              agent -> va_description(Entity);
                              avatar -> avatar_description(Entity)
                          end,
            ok = agent_bridge_client:describe(Client, Description),
            {noreply, S#s{client = Client}};
        {error, Why} ->
            {stop, {connect, Why}, S}
    end.

%% The first connect may meet a node still starting, or only standbys for a
%% moment after a failover: try again a few times.
connect(Eps, Opts, 0) ->
    agent_bridge_client:connect(Eps, Opts);
connect(Eps, Opts, N) ->
    case agent_bridge_client:connect(Eps, Opts) of
        {ok, C} -> {ok, C};
        {error, _} -> timer:sleep(250), connect(Eps, Opts, N - 1)
    end.

-spec handle_call(term(), gen_server:from(), #s{}) -> {reply, term(), #s{}} | {noreply, #s{}}.
handle_call(await_bound, _From, #s{bound = true} = S) ->
    {reply, ok, S};
handle_call(await_bound, From, S) ->
    {noreply, S#s{waiters = [{bound, From} | S#s.waiters]}};
handle_call(stop_traffic, _From, S) ->
    {reply, ok, S#s{running = false}};
handle_call(history, _From, S) ->
    {reply, #{entity => S#s.entity, role => S#s.role,
              sent => lists:reverse(S#s.sent), sent_at => S#s.sent_at,
              accepted_at => S#s.accepted_at, received_at => S#s.received_at,
              accepted => lists:reverse(S#s.accepted),
              received => lists:reverse(S#s.received), mediator => lists:reverse(S#s.mediator),
              reconnects => lists:reverse(S#s.reconnects), closed => S#s.closed}, S};
handle_call({since, Since}, _From, S) ->
    Received = maps:fold(fun(_, Ats, N) -> N + length([At || At <- Ats, At >= Since]) end,
                         0, S#s.received_at),
    %% Newest first: only the signals sent since Since are looked at.
    Recent = lists:takewhile(fun(Id) -> maps:get(Id, S#s.sent_at, Since) >= Since end, S#s.sent),
    Unacked = length([Id || Id <- Recent, not is_map_key(Id, S#s.accepted_at)]),
    {reply, #{received => Received, unacked => Unacked}, S};
handle_call({burst, N}, _From, #s{role = avatar} = S) ->
    {reply, ok, lists:foldl(fun(_, Acc) -> send_sensor(Acc) end, S, lists:seq(1, N))};
handle_call(status, _From, #s{client = C} = S) ->
    {reply, catch agent_bridge_client:status(C), S};
handle_call({round_trip, Timeout}, From, #s{role = agent} = S) ->
    {Id, S1} = send_request(S),
    erlang:send_after(Timeout, self(), {round_trip_timeout, Id}),
    {noreply, S1#s{waiters = [{Id, From} | S1#s.waiters]}}.

-spec handle_cast(term(), #s{}) -> {noreply, #s{}}.
handle_cast(_Msg, S) -> {noreply, S}.

-spec handle_info(term(), #s{}) -> {noreply, #s{}}.
handle_info({agent_bridge, C, Event}, #s{client = C} = S) ->
    {noreply, event(Event, S)};
handle_info({agent_bridge, _Old, _Event}, S) ->
    {noreply, S};
handle_info({'DOWN', _, process, _Owner, _}, S) ->
    {stop, normal, S};
handle_info({tick, What}, #s{running = true} = S) ->
    S1 = case What of
             request -> element(2, send_request(S));
             sensor -> send_sensor(S)
         end,
    schedule(What, S1),
    {noreply, S1};
handle_info({tick, _What}, S) ->
    {noreply, S};
handle_info({round_trip_timeout, Id}, #s{waiters = W} = S) ->
    case lists:keytake(Id, 1, W) of
        {value, {Id, From}, W1} ->
            gen_server:reply(From, {error, timeout}),
            {noreply, S#s{waiters = W1}};
        false ->
            {noreply, S}
    end;
handle_info(_Other, S) ->
    {noreply, S}.

-spec terminate(term(), #s{}) -> ok.
terminate(_Why, #s{client = undefined}) -> ok;
terminate(_Why, #s{client = C}) ->
    _ = catch agent_bridge_client:close(C),
    ok.

%% ---------------------------------------------------------------------------
%% Events from the client
%% ---------------------------------------------------------------------------

event({binding, #{bound := Bound}}, #s{bound = false} = S) when Bound =/= [] ->
    S1 = S#s{bound = true},
    schedule(request, S1),
    schedule(sensor, S1),
    reply_waiters(bound, ok, S1);
event({binding, _}, S) ->
    S;
event({accepted, Ids}, S) ->
    Now = erlang:monotonic_time(millisecond),
    S#s{accepted = lists:reverse(Ids, S#s.accepted),
        accepted_at = maps:merge(maps:from_list([{Id, Now} || Id <- Ids]), S#s.accepted_at)};
event({reconnected, Info}, S) ->
    S#s{reconnects = [Info#{at => erlang:monotonic_time(millisecond)} | S#s.reconnects]};
event({closed, Reason}, S) ->
    S#s{closed = Reason};
event({signal, #{sender := <<"EVATAR">>} = Sig}, S) ->
    S#s{mediator = [Sig | S#s.mediator]};
event({signal, #{id := Id, context := request} = Sig}, #s{role = avatar} = S) ->
    S1 = received(Id, Sig, S),
    send_feedback(Sig, S1);
event({signal, #{id := Id, context := Ctx, in_reply_to := ReplyTo} = Sig}, S)
  when Ctx =:= feedback ->
    S1 = received(Id, Sig, S),
    reply_waiters(ReplyTo, {ok, maps:get(epoch, Sig, undefined)}, S1);
event({signal, #{id := Id} = Sig}, S) ->
    received(Id, Sig, S);
event(_Other, S) ->
    S.

received(Id, Sig, #s{opts = Opts} = S) ->
    Epoch = maps:get(epoch, Sig, undefined),
    _ = case maps:get(notify, Opts, undefined) of
            undefined -> ok;
            Pid -> Pid ! {evatar_test_traffic, S#s.entity,
                          {received, Id, Epoch, erlang:monotonic_time(microsecond)}}
        end,
    S#s{received = [{Id, Epoch} | S#s.received],
        received_at = maps:update_with(Id, fun(Ts) -> [erlang:monotonic_time(millisecond) | Ts] end,
                                       [erlang:monotonic_time(millisecond)], S#s.received_at)}.

reply_waiters(Key, Reply, #s{waiters = W} = S) ->
    {Mine, Rest} = lists:partition(fun({K, _}) -> K =:= Key end, W),
    _ = [gen_server:reply(From, Reply) || {_, From} <- Mine],
    S#s{waiters = Rest}.

%% ---------------------------------------------------------------------------
%% Sending
%% ---------------------------------------------------------------------------

schedule(request, #s{role = agent, opts = Opts}) -> tick(request, Opts, request_interval);
schedule(sensor, #s{role = avatar, opts = Opts}) -> tick(sensor, Opts, sensor_interval);
schedule(_, _) -> ok.

tick(What, Opts, Key) ->
    case maps:get(Key, Opts, off) of
        off -> ok;
        Ms -> erlang:send_after(Ms, self(), {tick, What}), ok
    end.

send_request(#s{entity = E, counter = N} = S) ->
    Id = <<E/binary, "-r", (integer_to_binary(N + 1))/binary>>,
    S1 = send(S, #{id => Id, context => request,
                   sender => <<"LightEmulator01">>, receiver => <<"Light01">>,
                   body => #{category => <<"ACTUATOR">>, type => <<"TurnLightOn">>,
                             parameters => [{<<"Light">>, <<"yes">>}]}}),
    {Id, S1#s{counter = N + 1, sent = [Id | S1#s.sent]}}.

send_feedback(#{id := ReqId, sender := Requester, receiver := Me}, S) ->
    Id = <<"fb-", ReqId/binary>>,
    S1 = send(S, #{id => Id, context => feedback, in_reply_to => ReqId,
                   sender => Me, receiver => Requester,
                   body => #{category => <<"ACTUATOR">>, type => <<"TurnLightOn">>,
                             parameters => [{<<"Done">>, <<"yes">>}]}}),
    S1#s{sent = [Id | S1#s.sent]}.

send_sensor(#s{entity = E, counter = N} = S) ->
    Id = <<E/binary, "-s", (integer_to_binary(N + 1))/binary>>,
    S1 = send(S, #{id => Id, context => sensor_data,
                   sender => <<"Thermo01">>, receiver => <<"ThermoEmulator01">>,
                   body => #{category => <<"SENSOR">>, type => <<"Temperature">>,
                             parameters => [{<<"Value">>, <<"21">>}]}}),
    S1#s{counter = N + 1, sent = [Id | S1#s.sent]}.

%% A client that gave up (it says why in its last message) stops the
%% traffic; the history shows it as `closed'.
send(#s{client = C} = S0, #{id := Id} = Signal) ->
    S = S0#s{sent_at = (S0#s.sent_at)#{Id => erlang:monotonic_time(millisecond)}},
    case agent_bridge_client:send(C, Signal) of
        ok -> S;
        {error, closed} -> S#s{running = false, closed = closed_reason(S)}
    end.

closed_reason(#s{closed = undefined, client = C}) ->
    receive {agent_bridge, C, {closed, Reason}} -> Reason
    after 1000 -> closed
    end;
closed_reason(#s{closed = Reason}) ->
    Reason.

credential(agent) -> ?CRED_VA;
credential(avatar) -> ?CRED_AV.

%% ---------------------------------------------------------------------------
%% Descriptions
%% ---------------------------------------------------------------------------

%% @doc The VA's body: a light emulator consuming TurnLightOn, a thermometer
%% emulator providing the Temperature the Avatar's sensor streams (the
%% suites' shared VA, evatar_test_fixtures).
-spec va_description(binary()) -> bil:description().
va_description(Id) ->
    evatar_test_fixtures:va_description(Id).

%% @doc The Avatar's body: a light providing TurnLightOn and a thermometer.
-spec avatar_description(binary()) -> bil:description().
avatar_description(Id) ->
    evatar_test_fixtures:avatar_description(Id).
