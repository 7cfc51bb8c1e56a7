%% @doc The JSON meaning of the shared test vectors (test/vectors/README.md):
%% the Erlang terms of signals, control documents and descriptions turned
%% into the JSON the vectors' `expect' holds, and back. Used by the
%% generator (test/vectors/generate.escript) and by
%% agent_bridge_vectors_SUITE, so both read and write one meaning.
%% JSON values are those of evatar_json: maps with binary keys, lists,
%% binaries, integers, true, false, null.
-module(agent_bridge_vectors).

-export([to_json/1, from_json/1, encode/1, kind/1, root/1, pretty/1, vectors_dir/0,
         connect/1, send_frame/2, recv_frame/2, recv_frame_skipping/3, error_answer/3,
         frame/1, body/1]).

%% ---------------------------------------------------------------------------
%% Erlang term -> JSON
%% ---------------------------------------------------------------------------

%% @doc The meaning of one parsed frame document (bil_control:parse_frame/2).
-spec to_json({signal, bil:signal()} | {control, bil_control:control()}
              | {description, bil:description()}) -> map().
to_json({signal, S}) -> signal(S);
to_json({description, D}) -> description(D);
to_json({control, C}) -> control(C).

signal(#{id := Id, context := Context, sender := Sender, receiver := Receiver,
         in_reply_to := InReplyTo, timestamp := Ts, seq := Seq, epoch := Epoch,
         body := #{category := Cat, type := Type, parameters := Params}} = S) ->
    #{<<"context">> => context_wire(Context), <<"id">> => Id,
      <<"origin">> => case S of
                          #{origin := evatar} -> <<"EVATAR">>;
                          #{} -> null
                      end,
      <<"sender">> => Sender, <<"receiver">> => Receiver,
      <<"in_reply_to">> => null_if(InReplyTo), <<"timestamp">> => Ts,
      <<"sequence">> => null_if(Seq), <<"epoch">> => null_if(Epoch),
      <<"service">> => #{<<"category">> => Cat, <<"type">> => Type},
      <<"parameters">> => params(Params)}.

params(Params) ->
    [#{<<"name">> => N, <<"value">> => V} || {N, V} <- Params].

entry(#{category := Cat, type := Type, parameters := Params}) ->
    #{<<"category">> => Cat, <<"type">> => Type, <<"parameters">> => params(Params)}.

description(#{entity_id := Id, api_name := Api, entity_type := Type, context := Context,
              components := Components}) ->
    #{<<"entity_id">> => Id, <<"api_name">> => Api,
      <<"entity_type">> => case Type of agent -> <<"Agent">>; avatar -> <<"Avatar">> end,
      <<"context">> => Context,
      <<"components">> => [#{<<"id">> => CId,
                             <<"services">> => [entry(E) || E <- Services],
                             <<"consumes">> => [entry(E) || E <- Consumes]}
                           || #{id := CId, services := Services, consumes := Consumes}
                                  <- Components]}.

control({hello, H}) ->
    hello(<<"Hello">>, H);
control({resume, #{session_id := S, received := R, epoch := E} = H}) ->
    (hello(<<"Resume">>, H))#{<<"session_id">> => S, <<"received">> => R, <<"epoch">> => E};
control({welcome, #{pairing := P, entity_id := E, session_id := S, join_timeout := J,
                    max_frame := M} = W}) ->
    Ha = maps:get(ha, W, #{}),
    #{<<"control">> => <<"Welcome">>, <<"pairing">> => P, <<"entity_id">> => E,
      <<"session_id">> => S, <<"join_timeout">> => J, <<"max_frame">> => M,
      <<"epoch">> => maps:get(epoch, Ha, null), <<"resumed">> => maps:get(resumed, Ha, null),
      <<"last_accepted">> => maps:get(last_accepted, Ha, null),
      <<"dedup_window">> => maps:get(dedup_window, Ha, null),
      <<"heartbeat">> => maps:get(heartbeat, Ha, null)};
control({ack, A}) ->
    #{<<"control">> => <<"Ack">>, <<"accepted">> => maps:get(accepted, A, null),
      <<"received">> => maps:get(received, A, null)};
control({refused, #{code := C, message := M}}) ->
    #{<<"control">> => <<"Refused">>, <<"code">> => C, <<"message">> => M};
control({bye, Reason}) ->
    #{<<"control">> => <<"Bye">>, <<"reason">> => Reason};
control({get_binding, #{}}) ->
    #{<<"control">> => <<"GetBinding">>};
control({binding, #{entities := Ids, bound := Bound, unbound := Unbound}}) ->
    #{<<"control">> => <<"Binding">>, <<"entities">> => Ids,
      <<"bound">> => [#{<<"consumer_entity">> => CE, <<"consumer_component">> => CC,
                        <<"provider_entity">> => PE, <<"provider_component">> => PC,
                        <<"service_category">> => Cat, <<"service_type">> => Type,
                        <<"score">> => Score, <<"candidates">> => Cands}
                      || #{consumer := #{entity := CE, component := CC},
                           provider := #{entity := PE, component := PC},
                           category := Cat, type := Type, score := Score,
                           candidates := Cands} <- Bound],
      <<"unbound">> => [#{<<"consumer_entity">> => CE, <<"consumer_component">> => CC,
                          <<"service_category">> => Cat, <<"service_type">> => Type,
                          <<"reason">> => reason_wire(R)}
                        || #{consumer := #{entity := CE, component := CC},
                             category := Cat, type := Type, reason := R} <- Unbound]}.

hello(Root, #{pairing := P, role := Role, entity_id := E, credential := C,
              protocol_version := V}) ->
    #{<<"control">> => Root, <<"pairing">> => P, <<"role">> => atom_to_binary(Role),
      <<"entity_id">> => E, <<"credential">> => C, <<"protocol_version">> => V}.

null_if(undefined) -> null;
null_if(V) -> V.

context_wire(request) -> <<"RequestAwaitingFeedback">>;
context_wire(request_no_feedback) -> <<"Request">>;
context_wire(feedback) -> <<"Feedback">>;
context_wire(progress) -> <<"Progress">>;
context_wire(sensor_data) -> <<"SensorData">>;
context_wire(event) -> <<"Event">>;
context_wire(error) -> <<"Error">>.

reason_wire(no_provider) -> <<"NoProvider">>;
reason_wire(parameters_mismatch) -> <<"ParametersMismatch">>.

%% ---------------------------------------------------------------------------
%% JSON -> Erlang term (for encoding; the input is the committed vectors)
%% ---------------------------------------------------------------------------

%% @doc The term a JSON meaning stands for, tagged as parse_frame/2 tags it.
%% Crashes on JSON that is not a meaning (a defect of the vector file).
-spec from_json(map()) -> {signal, bil:signal()} | {control, bil_control:control()}
                              | {description, bil:description()}.
from_json(#{<<"control">> := Root} = J) ->
    {control, control_term(Root, J)};
from_json(#{<<"components">> := _} = J) ->
    {description, description_term(J)};
from_json(#{<<"service">> := #{<<"category">> := Cat, <<"type">> := Type}} = J) ->
    Origin = case get(<<"origin">>, J) of
                 <<"EVATAR">> -> #{origin => evatar};
                 null -> #{}
             end,
    {signal, Origin#{id => get(<<"id">>, J), context => context_term(get(<<"context">>, J)),
               sender => get(<<"sender">>, J), receiver => get(<<"receiver">>, J),
               in_reply_to => undef_if(get(<<"in_reply_to">>, J)),
               timestamp => get(<<"timestamp">>, J),
               seq => undef_if(get(<<"sequence">>, J)), epoch => undef_if(get(<<"epoch">>, J)),
               body => #{category => Cat, type => Type,
                         parameters => params_term(get(<<"parameters">>, J))}}}.

get(Key, Map) -> maps:get(Key, Map).

params_term(Params) ->
    [{get(<<"name">>, P), get(<<"value">>, P)} || P <- Params].

entry_term(E) ->
    #{category => get(<<"category">>, E), type => get(<<"type">>, E),
      parameters => params_term(get(<<"parameters">>, E))}.

description_term(J) ->
    #{entity_id => get(<<"entity_id">>, J), api_name => get(<<"api_name">>, J),
      entity_type => case get(<<"entity_type">>, J) of
                         <<"Agent">> -> agent;
                         <<"Avatar">> -> avatar
                     end,
      context => get(<<"context">>, J),
      components => [#{id => get(<<"id">>, C),
                       services => [entry_term(E) || E <- get(<<"services">>, C)],
                       consumes => [entry_term(E) || E <- get(<<"consumes">>, C)]}
                     || C <- get(<<"components">>, J)]}.

control_term(<<"Hello">>, J) ->
    {hello, hello_term(J)};
control_term(<<"Resume">>, J) ->
    {resume, (hello_term(J))#{session_id => get(<<"session_id">>, J),
                              received => get(<<"received">>, J),
                              epoch => get(<<"epoch">>, J)}};
control_term(<<"Welcome">>, J) ->
    W = #{pairing => get(<<"pairing">>, J), entity_id => get(<<"entity_id">>, J),
          session_id => get(<<"session_id">>, J), join_timeout => get(<<"join_timeout">>, J),
          max_frame => get(<<"max_frame">>, J)},
    case get(<<"epoch">>, J) of
        null -> {welcome, W};
        Epoch -> {welcome, W#{ha => #{epoch => Epoch, resumed => get(<<"resumed">>, J),
                                      last_accepted => get(<<"last_accepted">>, J),
                                      dedup_window => get(<<"dedup_window">>, J),
                                      heartbeat => get(<<"heartbeat">>, J)}}}
    end;
control_term(<<"Ack">>, J) ->
    {ack, maps:from_list([{accepted, A} || A <- [get(<<"accepted">>, J)], A =/= null] ++
                         [{received, R} || R <- [get(<<"received">>, J)], R =/= null])};
control_term(<<"Refused">>, J) ->
    {refused, #{code => get(<<"code">>, J), message => get(<<"message">>, J)}};
control_term(<<"Bye">>, J) ->
    {bye, get(<<"reason">>, J)};
control_term(<<"GetBinding">>, _J) ->
    {get_binding, #{}};
control_term(<<"Binding">>, J) ->
    {binding, #{entities => get(<<"entities">>, J),
                bound => [#{consumer => endpoint(<<"consumer">>, B),
                            provider => endpoint(<<"provider">>, B),
                            category => get(<<"service_category">>, B),
                            type => get(<<"service_type">>, B),
                            score => get(<<"score">>, B), candidates => get(<<"candidates">>, B)}
                          || B <- get(<<"bound">>, J)],
                unbound => [#{consumer => endpoint(<<"consumer">>, U),
                              category => get(<<"service_category">>, U),
                              type => get(<<"service_type">>, U),
                              reason => case get(<<"reason">>, U) of
                                            <<"NoProvider">> -> no_provider;
                                            <<"ParametersMismatch">> -> parameters_mismatch
                                        end}
                            || U <- get(<<"unbound">>, J)]}}.

endpoint(Side, Row) ->
    #{entity => get(<<Side/binary, "_entity">>, Row),
      component => get(<<Side/binary, "_component">>, Row)}.

hello_term(J) ->
    #{pairing => get(<<"pairing">>, J),
      role => case get(<<"role">>, J) of
                  <<"agent">> -> agent;
                  <<"avatar">> -> avatar
              end,
      entity_id => get(<<"entity_id">>, J), credential => get(<<"credential">>, J),
      protocol_version => get(<<"protocol_version">>, J)}.

undef_if(null) -> undefined;
undef_if(V) -> V.

context_term(<<"RequestAwaitingFeedback">>) -> request;
context_term(<<"Request">>) -> request_no_feedback;
context_term(<<"Feedback">>) -> feedback;
context_term(<<"Progress">>) -> progress;
context_term(<<"SensorData">>) -> sensor_data;
context_term(<<"Event">>) -> event;
context_term(<<"Error">>) -> error.

%% @doc The document a meaning stands for, written by the Erlang encoders.
-spec encode(map()) -> binary().
encode(Json) ->
    iolist_to_binary(case from_json(Json) of
                         {signal, S} -> bil:encode_signal(S);
                         {description, D} -> bil:encode_description(D);
                         {control, C} -> bil_control:encode(C)
                     end).

%% @doc The vector kind a meaning belongs to.
-spec kind(map()) -> binary().
kind(#{<<"control">> := _}) -> <<"control">>;
kind(#{<<"components">> := _}) -> <<"description">>;
kind(#{<<"service">> := _}) -> <<"signal">>.

%% @doc The root element's local name a meaning is written with.
-spec root(map()) -> binary().
root(#{<<"control">> := Root}) -> Root;
root(#{<<"components">> := _}) -> <<"description">>;
root(#{<<"service">> := _}) -> <<"Envelope">>.

%% ---------------------------------------------------------------------------
%% Writing vectors.json
%% ---------------------------------------------------------------------------

%% @doc JSON text indented by two spaces. `{obj, [{Key, Value}]}' is an
%% object whose keys keep that order; maps are written with sorted keys.
%% Scalars are written by evatar_json.
-spec pretty(term()) -> iodata().
pretty(V) -> [pretty(V, 0), $\n].

pretty({obj, []}, _) -> <<"{}">>;
pretty({obj, Pairs}, I) ->
    In = indent(I + 1),
    [${, lists:join($,, [[$\n, In, evatar_json:encode(K), <<": ">>, pretty(V, I + 1)]
                         || {K, V} <- Pairs]),
     $\n, indent(I), $}];
pretty(M, I) when is_map(M) ->
    pretty({obj, lists:sort(maps:to_list(M))}, I);
pretty([], _) -> <<"[]">>;
pretty(L, I) when is_list(L) ->
    case lists:all(fun(V) -> not is_map(V) andalso not is_list(V)
                                 andalso not is_tuple(V) end, L) of
        true ->
            [$[, lists:join(<<", ">>, [evatar_json:encode(V) || V <- L]), $]];
        false ->
            In = indent(I + 1),
            [$[, lists:join($,, [[$\n, In, pretty(V, I + 1)] || V <- L]), $\n, indent(I), $]]
    end;
pretty(V, _) ->
    evatar_json:encode(V).

indent(I) -> binary:copy(<<"  ">>, I).

%% ---------------------------------------------------------------------------
%% Where the vectors are
%% ---------------------------------------------------------------------------

%% @doc The repository's test/vectors directory: EVATAR_VECTORS_DIR if set,
%% else found by walking up from this module's source file, then from the
%% current directory.
-spec vectors_dir() -> file:filename().
vectors_dir() ->
    case os:getenv("EVATAR_VECTORS_DIR") of
        Dir when is_list(Dir), Dir =/= "" ->
            Dir;
        _ ->
            Source = proplists:get_value(source, ?MODULE:module_info(compile), "."),
            {ok, Cwd} = file:get_cwd(),
            Starts = [filename:dirname(resolve(Source)), Cwd],
            case lists:filtermap(fun walk_up/1, Starts) of
                [Dir | _] -> Dir;
                [] -> error({no_vectors_dir, Starts})
            end
    end.

resolve(Path) ->
    case file:read_link_all(Path) of
        {ok, Target} -> filename:absname(Target, filename:dirname(Path));
        {error, _} -> Path
    end.

walk_up(Dir) ->
    Candidate = filename:join([Dir, "test", "vectors"]),
    case filelib:is_regular(filename:join(Candidate, "vectors.json")) orelse
        filelib:is_regular(filename:join(Candidate, "generate.escript")) of
        true -> {true, Candidate};
        false ->
            case filename:dirname(Dir) of
                Dir -> false;
                Parent -> walk_up(Parent)
            end
    end.

%% ---------------------------------------------------------------------------
%% A client's TCP connection, frame by frame (passive, so that a test reads
%% exactly what it expects and nothing else)
%% ---------------------------------------------------------------------------

%% @doc Connects to 127.0.0.1:Port; frames are split by the runtime
%% (`{packet, 4}'), which is exactly the protocol's framing.
-spec connect(inet:port_number()) -> gen_tcp:socket().
connect(Port) ->
    {ok, S} = gen_tcp:connect({127, 0, 0, 1}, Port,
                              [binary, {active, false}, {packet, 4}, {nodelay, true}], 5000),
    S.

%% @doc Sends the bytes of whole frames (length prefixes included) as they are.
-spec send_frame(gen_tcp:socket(), binary()) -> ok.
send_frame(S, Bytes) ->
    ok = inet:setopts(S, [{packet, raw}]),
    ok = gen_tcp:send(S, Bytes),
    ok = inet:setopts(S, [{packet, 4}]).

%% @doc The next frame's bytes, length prefix included; `closed' or `timeout'.
-spec recv_frame(gen_tcp:socket(), timeout()) -> {ok, binary()} | closed | timeout.
recv_frame(S, Timeout) ->
    case gen_tcp:recv(S, 0, Timeout) of
        {ok, Doc} -> {ok, <<(byte_size(Doc)):32/big, Doc/binary>>};
        {error, timeout} -> timeout;
        {error, _} -> closed
    end.

%% @doc As recv_frame/2, but skips heartbeats (empty Acks) unless `Keep'.
-spec recv_frame_skipping(gen_tcp:socket(), timeout(), boolean()) ->
          {ok, binary()} | closed | timeout.
recv_frame_skipping(S, Timeout, Keep) ->
    case recv_frame(S, Timeout) of
        {ok, Frame} when not Keep ->
            case heartbeat(Frame) of
                true -> recv_frame_skipping(S, Timeout, Keep);
                false -> {ok, Frame}
            end;
        Other ->
            Other
    end.

heartbeat(<<_:32, Doc/binary>>) ->
    bil_control:parse_frame(Doc, #{}) =:= {ok, {control, {ack, #{}}}}.

%% @doc A document's frame, written by the Erlang encoders.
-spec frame(map() | {signal, bil:signal()} | {control, bil_control:control()}
            | {description, bil:description()}) -> binary().
frame(Json) when is_map(Json) ->
    frame(from_json(Json));
frame(Term) ->
    Doc = case Term of
              {signal, S} -> bil:encode_signal(S);
              {description, D} -> bil:encode_description(D);
              {control, C} -> bil_control:encode(C)
          end,
    iolist_to_binary(agent_bridge_frame:encode(Doc)).

%% @doc The document inside a frame.
-spec body(binary()) -> binary().
body(<<_:32, Doc/binary>>) -> Doc.

%% ---------------------------------------------------------------------------
%% Error vectors (README.md section 5.6)
%% ---------------------------------------------------------------------------

%% @doc Runs one error vector against the node listening on Port: the setup
%% (null, <<"agent_connected">> or <<"avatar_connected">>), a fresh
%% connection, Bytes sent at once, then the first answer that is not a
%% Welcome: `{Code, Close}', Code the Refused's Code or the Error signal's
%% ServiceType, Close whether the server closed the connection after it.
-spec error_answer(inet:port_number(), null | binary(), binary()) ->
          {binary(), boolean()}.
error_answer(Port, Setup, Bytes) ->
    Holder = setup(Port, Setup),
    S = connect(Port),
    ok = send_frame(S, Bytes),
    Answer = answer(S),
    ok = gen_tcp:close(S),
    ok = teardown(Holder),
    Answer.

answer(S) ->
    {ok, F} = recv_frame(S, 5000),
    case bil_control:parse_frame(body(F), #{}) of
        {ok, {control, {welcome, _}}} ->
            answer(S);
        {ok, {control, {refused, #{code := Code}}}} ->
            {Code, closes(S)};
        {ok, {signal, #{context := error, body := #{type := Type}}}} ->
            {Type, not still_open(S)}
    end.

%% After a Refused the server closes (after at most its linger): true when
%% the connection ends, false when anything else comes.
closes(S) ->
    recv_frame(S, 5000) =:= closed.

%% After an Error signal the connection stays: a Bye is answered by a Bye.
still_open(S) ->
    ok = send_frame(S, frame({control, {bye, <<>>}})),
    case recv_frame(S, 5000) of
        {ok, F} -> bil_control:parse_frame(body(F), #{}) =:= {ok, {control, {bye, <<>>}}};
        _ -> false
    end.

setup(_Port, null) ->
    none;
setup(Port, Which) ->
    {Role, Entity, Cred} = case Which of
                               <<"agent_connected">> -> {agent, <<"va-1">>, <<"va-secret">>};
                               <<"avatar_connected">> -> {avatar, <<"7008">>, <<"avatar-secret">>}
                           end,
    S = connect(Port),
    ok = send_frame(S, frame({control, {hello, #{pairing => <<"vectors">>, role => Role,
                                                  entity_id => Entity, credential => Cred,
                                                  protocol_version => 1}}})),
    {ok, F} = recv_frame(S, 5000),
    {ok, {control, {welcome, _}}} = bil_control:parse_frame(body(F), #{}),
    S.

teardown(none) ->
    ok;
teardown(S) ->
    ok = send_frame(S, frame({control, {bye, <<>>}})),
    {ok, _} = recv_frame(S, 5000),
    closed = recv_frame(S, 5000),
    gen_tcp:close(S).
